"""``ringtrack export LOG --csv DIR | --mcap FILE``: a run log as CSV tables, or as an MCAP recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from ringtrack.tools.cli.options import MCAP_FILE
from ringtrack.tools.output.console import UsageError, out
from ringtrack.tools.output.files import unwritable, write_csv
from ringtrack.tools.runlog.export import LINK_COLUMNS, STEP_COLUMNS, link_rows, step_rows
from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.viz.extra import VIZ_EXTRA, require_sdk
from ringtrack.tools.viz.sink import write_mcap


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("export", help="write a run log as CSV tables or as an MCAP recording for Foxglove",
                                 description="Write DIR/steps.csv (one row per step and robot) and DIR/links.csv "
                                 "(one row per message link) from a run log, and/or the run as MCAP with Foxglove's "
                                 "schemas (docs/foxglove.md).")
    parser.add_argument("log", type=Path, help="a run log (RUN_FOLDER/log.jsonl, or simulate --log)")
    parser.add_argument("--csv", type=Path, metavar="DIR", help="folder to write the tables to")
    parser.add_argument("--mcap", type=MCAP_FILE, metavar="FILE",
                        help=f"write the run as MCAP (3-D scene, frames, metrics, log), stamped with its simulated "
                        f"time ({VIZ_EXTRA})")
    parser.set_defaults(handler=run_export)


def run_export(args: argparse.Namespace) -> int:
    if args.csv is None and args.mcap is None:
        raise UsageError("export: give --csv DIR, --mcap FILE or both")
    if args.mcap is not None:
        require_sdk("--mcap")
    if args.csv is not None:  # checked before any work, as every output
        if args.csv.exists() and not args.csv.is_dir():
            raise UsageError(f"--csv {args.csv}: is a file; give a folder")
        for name in ("steps.csv", "links.csv"):
            if (problem := unwritable(args.csv / name)) is not None:
                raise UsageError(f"--csv {args.csv}: cannot write {name} there ({problem}); give a writable folder")
    log = read_log(args.log)
    if args.csv is not None:
        steps = write_csv(args.csv / "steps.csv", step_rows(log), STEP_COLUMNS)
        links = write_csv(args.csv / "links.csv", link_rows(log), LINK_COLUMNS)
        out.print(f"wrote {args.csv / 'steps.csv'} ({steps} rows) and {args.csv / 'links.csv'} ({links} rows)",
                  highlight=False, soft_wrap=True)
    if args.mcap is not None:
        write_mcap(log, args.mcap)
        out.print(f"wrote {args.mcap} ({len(log.steps)} steps, {len(log.events)} events)", highlight=False,
                  soft_wrap=True)
    return 0
