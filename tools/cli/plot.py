"""``ringtrack plot LOG -o PNG``: a run's trajectories, errors, polls and traffic in one figure;
``--animate FILE.gif|FILE.mp4``: the team over time."""

from __future__ import annotations

import argparse
from pathlib import Path

from ringtrack.tools.cli.options import FIGURE_SUFFIXES, at_least, output_path
from ringtrack.tools.output.console import UsageError, out
from ringtrack.tools.runlog.log import read_log
from ringtrack.tools.runlog.plot import plot_run
from ringtrack.tools.viz.animate import ANIMATION_SUFFIXES, animate_run


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("plot", help="draw a run log: trajectories, Cerr/Terr, polls, traffic per link; "
                                 "or animate it")
    parser.add_argument("log", type=Path, help="a run log (RUN_FOLDER/log.jsonl, or simulate --log)")
    parser.add_argument("-o", "--output", type=output_path(FIGURE_SUFFIXES), metavar="PNG",
                        help="figure to write (.png, .pdf or .svg)")
    parser.add_argument("--animate", type=output_path(ANIMATION_SUFFIXES), metavar="FILE.gif|FILE.mp4",
                        help="animation of the team over time: robots, target, estimates with 2-sigma ellipses, "
                        "the links that fired (GIF with pillow, MP4 with ffmpeg)")
    parser.add_argument("--fps", type=at_least(1), default=10, help="animation: frames per second (default 10)")
    parser.add_argument("--every", type=at_least(1), default=1, metavar="K",
                        help="animation: a frame every K steps (default 1: every step)")
    parser.set_defaults(handler=run_plot)


def run_plot(args: argparse.Namespace) -> int:
    if args.output is None and args.animate is None:
        raise UsageError("plot: give -o PNG, --animate FILE.gif or both")
    log = read_log(args.log)
    if not log.steps:
        raise UsageError(f"{args.log}: the log has no steps to draw")
    if args.output is not None:
        plot_run(log).savefig(args.output, dpi=110)
        out.print(f"wrote {args.output}", highlight=False)
    if args.animate is not None:
        frames = animate_run(log, args.animate, fps=args.fps, every=args.every)
        out.print(f"wrote {args.animate} ({frames} frames)", highlight=False)
    return 0
