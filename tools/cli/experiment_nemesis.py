"""``ringtrack experiment nemesis``: random fault schedules against live teams, each checked."""

from __future__ import annotations

import argparse
from pathlib import Path

from rich import box
from rich.table import Table

from ringtrack.tools.cli.options import add_output_arguments, at_least, write_study
from ringtrack.tools.output.console import err, out, show
from ringtrack.tools.output.progress import TrialProgress
from ringtrack.tools.studies.figures import plot_schedules
from ringtrack.tools.studies.nemesis import LEASE_S, ScheduleRow, nemesis_study
from ringtrack.tools.team.nemesis import parse_plan
from ringtrack.world.scenario import load_scenario

CLOCKS = {"lockstep": ("lockstep",), "realtime": ("realtime",), "both": ("lockstep", "realtime")}


def register(kinds: argparse._SubParsersAction) -> None:
    parser = kinds.add_parser(
        "nemesis",
        help="random process-fault schedules against live six-robot teams: re-formed?, tracking after, "
        "overlapping lives, balanced books, lost monitor/world noticed, restarted monitor resumed",
        description="Run seeded random nemesis schedules (robots killed and restarted as their next life, paused "
        f"below and past the {LEASE_S:g} s liveliness lease, split brains, ring links partitioned; every fifth "
        "schedule also kills the monitor or the world, or kills the monitor and restarts it) against spawned teams "
        "with the wire audit on, alternating the clocks, and check each run: did the ring re-form and when, the "
        "tracking after it, overlapping lives (must be 0), balanced books (must be), whether a lost monitor or world "
        "was noticed and whether a restarted monitor resumed the log whole.",
    )
    parser.add_argument("scenario", nargs="?", default="authors-moving", help="scenario (default authors-moving)")
    parser.add_argument("--schedules", type=at_least(1), default=50, help="random schedules (default 50)")
    parser.add_argument("--seed", type=at_least(0), default=0, help="seed of schedule 0 (default 0)")
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="both", help="which clocks (default both)")
    parser.add_argument("--steps", type=at_least(50), default=600, help="steps per run (default 600)")
    parser.add_argument("--settle", type=at_least(0), default=100,
                        help="tracking after the fault is averaged from this step on at the earliest (default 100)")
    parser.add_argument("--plan", metavar="PLAN",
                        help="run this one nemesis plan in every schedule instead of random ones, e.g. the split "
                        "brain 'pause r3@1s:6s, restart r3@4s' (the syntax of spawn --nemesis)")
    parser.add_argument("--runs", type=Path, help="keep the run folders here (default: a scratch folder)")
    parser.add_argument("--quiet", action="store_true", help="no progress")
    add_output_arguments(parser, json="write every schedule's row and the totals", plot="draw the schedules")
    parser.set_defaults(handler=run_nemesis)


def run_nemesis(args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario, robots=6, max_steps=args.steps)
    fixed = None if args.plan is None else parse_plan(args.plan, scenario.robots)
    with TrialProgress("nemesis", args.schedules, quiet=args.quiet) as progress:
        study = nemesis_study(scenario, args.schedules, args.seed, CLOCKS[args.clock], args.settle,  # type: ignore[arg-type]
                              on_row=lambda row: progress.advance(1), runs=args.runs, fixed=fixed)
    show(schedule_table(study.rows), out)
    out.print(f"{study.schedules} schedules: overlapping lives {study.overlapping_lives}, unbalanced books "
              f"{study.unbalanced_books}, lost monitor or world noticed {study.lost_noticed}, restarted monitor "
              f"resumed the log {study.monitors_resumed}, re-formed {study.reformed}", highlight=False)
    if study.fenced_within_s is not None:
        out.print(f"every replaced life stopped within {study.fenced_within_s:.1f} s of its waking "
                  f"(lease {LEASE_S:g} s)", highlight=False)
    write_study(args, study, plot_schedules)
    failed = study.overlapping_lives or study.unbalanced_books or not _all(study.lost_noticed) \
        or not _all(study.monitors_resumed)
    if failed:
        err.print("ringtrack: error: the nemesis broke something (see the table)", highlight=False)
    return 1 if failed else 0


def _all(fraction: str) -> bool:
    done, total = fraction.split("/")
    return done == total


def schedule_table(rows: list[ScheduleRow]) -> Table:
    table = Table(title="nemesis schedules (wire audit on)", box=box.SIMPLE)
    for column in ("#", "clock", "plan", "exit", "re-formed at", "Cerr after", "Terr after", "lives fenced",
                   "overlaps", "books", "lost noticed", "resumed"):
        table.add_column(column, justify="left" if column == "plan" else "right")
    for row in rows:
        table.add_row(str(row.schedule), row.clock, row.plan, str(row.exit_code),
                      "-" if row.reformed_at_step is None else f"step {row.reformed_at_step}",
                      "-" if row.cerr_after_deg is None else f"{row.cerr_after_deg:.1f} deg",
                      "-" if row.terr_after_m is None else f"{row.terr_after_m:.3f} m",
                      str(row.fenced_lives) + (f" ({max(row.fenced_after_s):.1f} s)" if row.fenced_after_s else ""),
                      str(row.overlapping_lives),
                      "balanced" if row.books_balanced else "UNBALANCED",
                      "-" if row.noticed is None else "yes" if row.noticed else "NO",
                      "-" if row.resumed is None else "yes" if row.resumed else "NO")
    return table
