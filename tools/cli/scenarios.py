"""``ringtrack scenarios generate``: seeded random scenario files (:mod:`world.scenario_generator`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ringtrack.tools.cli.options import at_least
from ringtrack.tools.output.console import UsageError, out
from ringtrack.tools.output.files import written_whole
from ringtrack.world.scenario_generator import MOTIONS, ROBOTS, file_name, scenario_text
from ringtrack.world.scenario_schema import MAX_ROBOTS


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("scenarios", help="make scenario files")
    kinds = parser.add_subparsers(dest="scenarios", required=True, metavar="ACTION")
    generate = kinds.add_parser(
        "generate",
        help="write seeded random scenarios (convex regions, teams, moving targets) as TOML files",
        description="Write --count random scenarios, gen-0000.toml, gen-0001.toml, ..., into --out: a convex "
        "region of 4-10 vertices tens of metres across, a team of --robots robots, and a target that stays "
        "inside and that the robots can keep up with, its motion cycling through --motion. File i is drawn "
        "from numpy.random.default_rng([SEED, i]) alone: the same seed writes the same bytes, and a smaller "
        "--count writes the first files of a larger one. Existing files of those names are replaced.",
    )
    generate.add_argument("--count", type=at_least(1), default=10, metavar="N", help="scenarios to write (default 10)")
    generate.add_argument("--seed", type=at_least(0), default=0, metavar="S", help="generator seed (default 0)")
    generate.add_argument("--out", type=Path, default=Path("generated"), metavar="DIR",
                          help="folder to write them in, made if missing (default generated/)")
    generate.add_argument("--motion", type=motion_list, default=list(MOTIONS), metavar="A,B",
                          help=f"target motions, taken in turn (default {','.join(MOTIONS)})")
    generate.add_argument("--robots", type=robot_range, default=ROBOTS, metavar="MIN-MAX",
                          help="team sizes drawn uniformly from MIN..MAX, or one size "
                          f"(default {ROBOTS[0]}-{ROBOTS[1]})")
    generate.set_defaults(handler=run_generate)


def motion_list(text: str) -> list[str]:
    """Parse ``circle,waypoints`` into target motions (each once, in the order given)."""
    motions = [part.strip() for part in text.split(",") if part.strip()]
    unknown = [motion for motion in motions if motion not in MOTIONS]
    if not motions or unknown:
        raise argparse.ArgumentTypeError(f"{text!r}: give motions among {','.join(MOTIONS)}")
    if len(set(motions)) < len(motions):
        raise argparse.ArgumentTypeError(f"{text!r} names a motion twice; give each once")
    return motions


def robot_range(text: str) -> tuple[int, int]:
    """Parse ``4-12`` (or ``6``) into the least and most robots of a team, both >= 3."""
    low, _, high = text.partition("-")
    try:
        least, most = int(low), int(high or low)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give team sizes like 4-12 or 6") from None
    if not 3 <= least <= most <= MAX_ROBOTS:
        raise argparse.ArgumentTypeError(f"{text!r}: give 3 <= MIN <= MAX <= {MAX_ROBOTS}, e.g. 4-12")
    return least, most


def run_generate(args: argparse.Namespace) -> int:
    folder: Path = args.out
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"--out {folder}: is a file; give a folder")
    for index in range(args.count):
        with written_whole(folder / file_name(index)) as file:
            file.write(scenario_text(args.seed, index, args.motion, args.robots).decode())
    out.print(f"wrote {args.count} scenarios to {folder}/ ({file_name(0)} .. {file_name(args.count - 1)})",
              highlight=False, soft_wrap=True)
    return 0
