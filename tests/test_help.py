"""Every flag and positional of every ``ringtrack`` command says what it is for."""

from __future__ import annotations

import argparse
from importlib import metadata

import pytest

from ringtrack.tools.cli import COMMANDS, build_parser, main, modules_for


def walk(parser: argparse.ArgumentParser, path: str = "ringtrack") -> list[tuple[str, argparse.Action]]:
    """``(command path, action)`` of every argument of ``parser`` and of all its sub-commands."""
    found: list[tuple[str, argparse.Action]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                found += walk(child, f"{path} {name}")
        elif not isinstance(action, argparse._HelpAction):
            found.append((path, action))
    return found


def test_every_argument_of_every_command_has_help() -> None:
    actions = walk(build_parser(COMMANDS))
    assert len({path for path, _ in actions}) >= 16  # every command and sub-command was walked
    missing = [f"{path} {'/'.join(action.option_strings) or action.dest}" for path, action in actions
               if action.help != argparse.SUPPRESS and not (action.help or "").strip()]
    assert not missing, "arguments without help text: " + ", ".join(missing)


def test_every_command_has_a_one_line_help() -> None:
    parser = build_parser(COMMANDS)
    subcommands = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
    listed = {choice.dest: choice.help for choice in subcommands._choices_actions}
    assert set(listed) == set(subcommands.choices)
    assert all(help_text and help_text.strip() for help_text in listed.values()), listed


def test_the_command_table_names_what_each_module_registers() -> None:
    """``cli.COMMANDS`` picks the one module a command line needs: it must list exactly the commands
    each module's ``register`` adds, or a command would be built without its module."""
    for module, names in COMMANDS.items():
        parser = build_parser([module])
        subcommands = next(action for action in parser._actions if isinstance(action, argparse._SubParsersAction))
        assert tuple(subcommands.choices) == names, module


def test_a_command_line_builds_only_its_module() -> None:
    assert modules_for(["spawn", "--steps", "5"], tuple(COMMANDS)) == ["spawn"]
    assert modules_for(["hz", "RUN"], tuple(COMMANDS)) == ["introspect"]
    assert modules_for(["--help"], tuple(COMMANDS)) == list(COMMANDS)
    assert modules_for(["spwan"], tuple(COMMANDS)) == list(COMMANDS)  # the error lists every command
    assert modules_for([], ("roles",)) == ["roles"]


def test_version_names_the_installed_distribution(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["--version"])
    assert exited.value.code == 0
    assert capsys.readouterr().out.strip() == f"ringtrack {metadata.version('ringtrack')}"
