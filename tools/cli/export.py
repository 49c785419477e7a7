"""``ringtrack export LOG --csv DIR``: a run log as CSV tables (per step and robot, per link)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ringtrack.tools.output.console import UsageError, out
from ringtrack.tools.output.files import write_csv
from ringtrack.tools.runlog.export import LINK_COLUMNS, STEP_COLUMNS, link_rows, step_rows
from ringtrack.tools.runlog.log import read_log


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("export", help="write a run log as CSV tables (per step and robot, per link)",
                                 description="Write DIR/steps.csv (one row per step and robot) and DIR/links.csv "
                                 "(one row per message link) from a run log.")
    parser.add_argument("log", type=Path, help="a run log (RUN_FOLDER/log.jsonl, or simulate --log)")
    parser.add_argument("--csv", type=Path, required=True, metavar="DIR", help="folder to write the tables to")
    parser.set_defaults(handler=run_export)


def run_export(args: argparse.Namespace) -> int:
    log = read_log(args.log)
    if args.csv.exists() and not args.csv.is_dir():
        raise UsageError(f"--csv {args.csv}: is a file; give a folder")
    steps = write_csv(args.csv / "steps.csv", step_rows(log), STEP_COLUMNS)
    links = write_csv(args.csv / "links.csv", link_rows(log), LINK_COLUMNS)
    out.print(f"wrote {args.csv / 'steps.csv'} ({steps} rows) and {args.csv / 'links.csv'} ({links} rows)",
              highlight=False, soft_wrap=True)
    return 0
