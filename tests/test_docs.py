"""The documentation site builds in strict mode (no broken link or anchor), its generated references
name every command and every scenario section and key, and the README stays a short front page.

The site is built once per module with ``python -m mkdocs build --strict`` from the repository root;
the generated pages are read back from the built HTML, so what is checked is what a reader sees. The
commands and schema keys are walked here independently of the hook that renders them
(docs/hooks/reference.py)."""

from __future__ import annotations

import argparse
import html
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest

from ringtrack.tools.cli import build_parser, main
from ringtrack.world.scenario_schema import ScenarioSpec

pytestmark = [pytest.mark.processes, pytest.mark.timeout(300)]

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
README_MAX_LINES = 300


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The site, built with --strict into a temporary folder; the build's output on failure."""
    site_dir = tmp_path_factory.mktemp("site")
    completed = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site_dir)],
                               cwd=ROOT, capture_output=True, text=True, timeout=240)
    assert completed.returncode == 0, (f"mkdocs build --strict exited with {completed.returncode}:\n"
                                       f"{completed.stdout}\n{completed.stderr}")
    return site_dir


def text_of(page: Path) -> str:
    """A built page's text: tags dropped, entities decoded, whitespace collapsed."""
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", page.read_text())).split())


def commands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*prefix, name)
                yield from commands(sub, (*prefix, name))


def structs(info: object) -> list[msgspec.inspect.StructType]:
    """The tables a field's type opens: a struct, the variants of a union, the items of a list."""
    inspect = msgspec.inspect
    if isinstance(info, inspect.StructType):
        return [info]
    if isinstance(info, inspect.UnionType):
        return [item for item in info.types if isinstance(item, inspect.StructType)]
    if isinstance(info, inspect.ListType):
        return structs(info.item_type)
    return []


def schema(info: object, path: str = "") -> Iterator[tuple[str, str, bool]]:
    """(path, key, opens a table) of every key of the scenario schema, depth first."""
    for struct in structs(info):
        for field in struct.fields:
            name = f"{path}.{field.encode_name}" if path else field.encode_name
            yield path, field.encode_name, bool(structs(field.type))
            yield from schema(field.type, name)


def test_the_site_builds_strict(site: Path) -> None:
    for page in ("index.html", "tutorial/index.html", "cli/index.html", "scenario-reference/index.html",
                 "algorithms/index.html", "strategies/index.html", "results/index.html"):
        assert (site / page).is_file(), f"the site has no {page}"


def test_the_cli_reference_names_every_command(site: Path) -> None:
    page = text_of(site / "cli" / "index.html")
    found = list(commands(build_parser()))
    assert len(found) > 10
    missing = [" ".join(words) for words in found if f"ringtrack {' '.join(words)}" not in page]
    assert not missing, f"the CLI reference does not name: {missing}"


def test_the_cli_reference_names_every_flag_of_spawn(site: Path) -> None:
    page = text_of(site / "cli" / "index.html")
    spawn = next(sub for action in build_parser()._actions if isinstance(action, argparse._SubParsersAction)
                 for name, sub in action.choices.items() if name == "spawn")
    flags = [option for action in spawn._actions for option in action.option_strings if option.startswith("--")]
    missing = [flag for flag in flags if flag not in page]
    assert not missing, f"the CLI reference does not name spawn's {missing}"


def test_the_scenario_reference_names_every_section_and_key(site: Path) -> None:
    built = (site / "scenario-reference" / "index.html").read_text()
    page = text_of(site / "scenario-reference" / "index.html")
    keys = list(schema(msgspec.inspect.type_info(ScenarioSpec)))
    assert {"region", "target", "control", "faults", "radio"} <= {key for path, key, _ in keys if not path}
    missing = []
    for path, key, table in keys:
        name = f"{path}.{key}" if path else key
        if table:  # a section: its header, [name] or [[name]]
            if f"[{name}]" not in page:
                missing.append(f"[{name}]")
        elif f"<code>{key}</code>" not in built:  # a key: a row of its section's table
            missing.append(name)
    assert not missing, f"the scenario reference does not name: {missing}"


def test_readme_is_a_short_front_page() -> None:
    lines = README.read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; at most {README_MAX_LINES}"
    top = "\n".join(lines[:8])
    assert "make run" in top and "make test" in top, "README.md must open with make run and make test"
    text = README.read_text()
    assert "Zhou" in text and "Tokekar" in text and "IEEE Transactions on Automation Science and Engineering" in text


def test_readme_links_resolve() -> None:
    links = re.findall(r"\]\(([^)\s]+)\)", README.read_text())
    local = [link.split("#", 1)[0] for link in links if not re.match(r"[a-z]+:", link) and not link.startswith("#")]
    assert local, "README.md links to no page of the docs"
    missing = [link for link in local if link and not (ROOT / link).exists()]
    assert not missing, f"README.md links to files that do not exist: {missing}"


def test_no_diaries_and_no_missing_documents() -> None:
    """Docs show current results: no before/after files, no citations of documents that are not here."""
    docs = ROOT / "docs"
    assert not [path.name for path in docs.glob("*") if re.search(r"-(before|after)\.", path.name)]
    for path in [README, *docs.glob("*.md")]:
        text = path.read_text()
        for name in ("ALGORITHMS.md", "DESIGN.md"):
            assert name not in text, f"{path.name} cites {name}, which is not in the repository"
        assert not re.search(r"\bshared/", text), f"{path.name} cites a folder named shared"


@pytest.mark.parametrize(("page", "command"), [("strategies.md", "simulate --strategy lazy"),
                                                ("tutorial.md", "spawn --drop 1.5")])
def test_a_quoted_error_is_the_one_printed(page: str, command: str, capsys: pytest.CaptureFixture[str]) -> None:
    """An error line a page quotes under ``$ ringtrack COMMAND`` is the line that command prints."""
    quoted = re.search(rf"^\$ ringtrack {re.escape(command)}\n(ringtrack: error: .*)$", (ROOT / "docs" / page).read_text(),
                       re.M)
    assert quoted, f"docs/{page} quotes no error of ringtrack {command}"
    assert main(command.split()) == 2
    assert capsys.readouterr().err.splitlines()[-1] == quoted.group(1)
