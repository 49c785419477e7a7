"""``ringtrack world``, ``ringtrack robot --id I`` and ``ringtrack monitor``: one role per process,
so a team can be assembled by hand or across hosts (``spawn`` starts exactly these)."""

from __future__ import annotations

import argparse
import asyncio
from pathlib import Path
from typing import NoReturn

from ringtrack.bus.config import LEASE_S, LOOPBACK_ANY_PORT, BusConfig
from ringtrack.bus.keys import FUSION, MONITOR, ROUTER, WORLD, robot_name
from ringtrack.tools.console import UsageError, err, out
from ringtrack.tools.options import (
    LOG_FILE,
    add_scenario_arguments,
    positive,
    scenario_from_arguments,
    warn_if_threshold_loose,
)

SECURE_HELP = "team folder made by ringtrack certs: mutual TLS on every link (tls/ endpoints), access control"


def register(commands: argparse._SubParsersAction) -> None:
    world = commands.add_parser("world", help="run the world process of a team")
    _common(world)
    world.add_argument("--clock", choices=["lockstep", "realtime"], default="lockstep",
                       help="lockstep: wait for every robot each step; realtime: a step every dt / rate wall "
                       "seconds (default lockstep)")
    world.add_argument("--rate", type=positive, default=1.0, help="realtime: simulated seconds per wall second")
    world.add_argument("--lockstep-wait", type=positive, default=10.0, metavar="S",
                       help="lockstep: treat a robot silent this many seconds in one step as gone (default 10)")
    world.add_argument("--announce", type=Path, metavar="PATH",
                       help="write the endpoints the world listens on to PATH (JSON)")
    world.set_defaults(handler=run_world_role)

    robot = commands.add_parser("robot", help="run one robot process")
    _common(robot)
    robot.add_argument("--id", type=robot_ids, required=True, metavar="I",
                       help="robot index 0..N-1 in counter-clockwise order; 0-7 or 0,2,4 runs several robots in "
                       "this process, each its own Zenoh participant")
    robot.add_argument("--reply-timeout", type=positive, metavar="S",
                       help="wall seconds a poll waits for replies (spawn: a step period in realtime, half the "
                       "--lockstep-wait in lockstep; default: wait)")
    robot.add_argument("--join", type=Path, metavar="RUN_FOLDER",
                       help="join the running team of a spawn run folder (scenario, run id, endpoints)")
    robot.set_defaults(handler=run_robot_role)

    router = commands.add_parser(
        "router",
        help="run a Zenoh router for teams spread over several hosts",
        description="A Zenoh router (no zenohd needed): hosts connect to it with --connect "
        "tcp/<router-ip>:<port> (as --mode client, or as peers). It serves every run; stop it with Ctrl-C.",
    )
    router.add_argument("--listen", action="append", metavar="ENDPOINT", required=True,
                        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447; repeatable")
    router.add_argument("--connect", action="append", metavar="ENDPOINT", help="another router; repeatable")
    router.add_argument("--announce", type=Path, metavar="PATH",
                        help="write the endpoints the router listens on to PATH (JSON; useful with port 0)")
    router.add_argument("--secure", type=Path, metavar="DIR", help=SECURE_HELP)
    _lease(router)
    router.add_argument("--exit-with-parent", action="store_true", help=argparse.SUPPRESS)
    router.set_defaults(handler=run_router_role)

    fusion = commands.add_parser("fusion", help="run the fusion centre of centralized estimation")
    _common(fusion)
    fusion.set_defaults(handler=run_fusion_role)

    monitor = commands.add_parser("monitor", help="tally a team's messages live and write its run log")
    _common(monitor)
    monitor.add_argument("--log", type=LOG_FILE, required=True, metavar="PATH", help="run log to write (JSON lines)")
    monitor.add_argument("--clock", choices=["lockstep", "realtime"], default="lockstep",
                         help="the world's clock, shown on the dashboard and written to the log (default lockstep)")
    display = monitor.add_mutually_exclusive_group()
    display.add_argument("--dashboard", action="store_true", help="draw the live dashboard even without a terminal")
    display.add_argument("--no-dashboard", action="store_true", help="plain summary lines instead of the dashboard")
    monitor.add_argument("--connect-from", type=Path, metavar="PATH",
                         help="wait for PATH (written by world --announce) and connect to the endpoints it lists; "
                         "the dashboard shows the start-up meanwhile")
    monitor.add_argument("--display-handover", type=Path, metavar="PATH",
                         help="spawn draws the start-up frame and wrote PATH: count from its time, write 'ready' "
                         "there when ready to draw, and draw once spawn has removed PATH (or after 30 s)")
    monitor.add_argument("--all-robots", action="store_true",
                         help="list every robot and link in the end-of-run report (default: above 20, "
                         "min/median/max and the 5 busiest)")
    monitor.set_defaults(handler=run_monitor_role)


def _common(parser: argparse.ArgumentParser) -> None:
    add_scenario_arguments(parser, steps_help="run exactly this many steps (default: the world ends the run at "
                           "convergence, at most control.max_steps)")
    parser.add_argument("--run", type=run_id, default=0, metavar="HEX", help="run id shared by the team (hex)")
    parser.add_argument("--mode", choices=["peer", "router", "client"], default="peer", help="Zenoh mode")
    parser.add_argument("--listen", action="append", metavar="ENDPOINT",
                        help=f"endpoint to listen on (default {LOOPBACK_ANY_PORT}); repeatable")
    parser.add_argument("--connect", action="append", metavar="ENDPOINT", help="endpoint to connect to; repeatable")
    parser.add_argument("--monitor", action="store_true", help="a monitor is part of the team: wait for it")
    parser.add_argument("--secure", type=Path, metavar="DIR", help=SECURE_HELP)
    _lease(parser)
    parser.add_argument("--audit", action="store_true",
                        help="the monitor receives a copy of every message and counts it itself (an independent "
                        "tally); by default, in lockstep, it takes the world's own counts of measurements and "
                        "commands instead; give it to the world and the monitor alike")
    parser.add_argument("--exit-with-parent", action="store_true", help=argparse.SUPPRESS)


def _lease(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--lease", type=positive, default=LEASE_S, metavar="S",
                        help=f"liveliness lease: a participant silent this many seconds (frozen, cut off) is seen "
                        f"gone by the others; give every process of a team the same (default {LEASE_S:g})")


def robot_ids(text: str) -> list[int]:
    """``3``, ``0-7`` or ``0,2,4``."""
    try:
        ids: list[int] = []
        for part in text.split(","):
            first, _, last = part.partition("-")
            span = range(int(first), int(last or first) + 1)
            if not span:
                raise ValueError(part)
            ids += list(span)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--id {text!r}: give a robot index like 3, or ascending ones like 0-7 or 0,2,4") from None
    if len(set(ids)) != len(ids):
        raise argparse.ArgumentTypeError(f"--id {text!r} names a robot twice; give each robot once")
    return ids


def run_id(text: str) -> int:
    try:
        value = int(text, 16)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--run {text!r}: give the run id in hex, e.g. 1f2e3d4c") from None
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"--run {text!r}: the run id has at most 8 hex digits")
    return value


def bus_config(args: argparse.Namespace, names: list[str], robots: int | None, admin_space: bool = False) -> BusConfig:
    """The bus of participants ``names`` (of a team of ``robots``) from the role's flags; with
    ``--secure DIR`` mutual TLS and access control (:func:`ringtrack.bus.security.secure_config`)."""
    listen, connect = tuple(args.listen or (LOOPBACK_ANY_PORT,)), tuple(args.connect or ())
    lease_ms = round(args.lease * 1000)
    if args.secure is None:
        return BusConfig(mode=args.mode, listen=listen, connect=connect, admin_space=admin_space, lease_ms=lease_ms)
    from ringtrack.bus.security import secure_config

    return secure_config(args.secure, names, robots, args.mode, listen, connect, admin_space, lease_ms)


def digests(args: argparse.Namespace) -> bool:
    """Whether the world reports to the monitor in digests (lockstep without ``--audit``) its own
    links and the robots' own counts of their robot-to-robot messages, rather than the monitor
    receiving a copy of every measurement, command, request, reply and push."""
    return args.clock == "lockstep" and not args.audit


def run_world_role(args: argparse.Namespace) -> int:
    from ringtrack.agents.strategy import check_strategy
    from ringtrack.world.process import WorldOptions, run_world

    scenario = scenario_from_arguments(args)
    warn_if_threshold_loose(scenario)
    options = WorldOptions(
        steps=scenario.max_steps,
        clock=args.clock,
        rate=args.rate,
        expect_monitor=args.monitor,
        announce=args.announce,
        until_converged=args.steps is None,  # as spawn and simulate: --steps K runs exactly K steps
        lockstep_wait=args.lockstep_wait,
        digest=args.monitor and digests(args),
        cerr=check_strategy(scenario).cerr,
    )
    config = bus_config(args, [WORLD], scenario.robots, admin_space=args.announce is not None)
    return asyncio.run(run_world(scenario, scenario.seed, args.run, config, options, args.exit_with_parent))


def run_robot_role(args: argparse.Namespace) -> int:
    from ringtrack.agents.process import run_robots

    if args.join is not None:
        join(args)
    scenario = scenario_from_arguments(args)
    for robot in args.id:
        if not 0 <= robot < scenario.robots:
            raise UsageError(f"--id {robot}: the team has robots 0..{scenario.robots - 1}")
    return finished("robot", asyncio.run(
        run_robots(args.id, scenario, args.run, bus_config(args, [robot_name(robot) for robot in args.id],
                                                           scenario.robots), args.monitor, args.exit_with_parent,
                   args.reply_timeout)
    ))


def join(args: argparse.Namespace) -> None:
    """Fill scenario, run id, endpoints and reply timeout from a spawn run folder."""
    import json

    run_file = args.join / "run.json"
    if not run_file.is_file():
        raise UsageError(f"--join {args.join}: no run.json there; give the folder of a running spawn")
    run = json.loads(run_file.read_text())
    args.scenario = str(args.join / "scenario.toml")
    args.run = int(run["run"], 16)
    args.connect = run["connect"]
    args.monitor = True
    if args.secure is None and run.get("secure"):
        args.secure = Path(run["secure"])
    if args.reply_timeout is None:
        args.reply_timeout = run["reply_timeout"]
    args.lease = run.get("lease_s", args.lease)


def run_router_role(args: argparse.Namespace) -> int:
    """A Zenoh router until SIGINT, SIGTERM or (``--exit-with-parent``) the end of standard input."""
    import os
    import signal
    import sys
    import threading

    from ringtrack.bus.config import announce_endpoints, listening_locators, open_session

    args.mode = "router"
    config = bus_config(args, [ROUTER], None, admin_space=True)
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    if args.exit_with_parent:
        def wait_for_parent() -> None:
            while os.read(sys.stdin.fileno(), 4096):
                pass
            stop.set()

        threading.Thread(target=wait_for_parent, daemon=True).start()
    with open_session(config, ROUTER) as session:
        if args.announce is not None:
            announce_endpoints(session, args.announce)
        err.print(f"router listening on {', '.join(listening_locators(session))}; Ctrl-C to stop", highlight=False)
        stop.wait()
    return 0


def run_fusion_role(args: argparse.Namespace) -> int:
    from ringtrack.agents.centre import run_fusion

    scenario = scenario_from_arguments(args)
    if scenario.estimation.mode != "centralized":
        raise UsageError(f"the scenario's estimation.mode is {scenario.estimation.mode!r}; a fusion centre serves "
                         "only 'centralized'")
    return finished("fusion", asyncio.run(
        run_fusion(scenario, args.run, bus_config(args, [FUSION], scenario.robots), args.monitor,
                   args.exit_with_parent)))


def run_monitor_role(args: argparse.Namespace) -> int:
    import signal

    from rich.console import Console

    from ringtrack.tools.dashboard import TeamModel, startup_names
    from ringtrack.tools.monitor import run_monitor
    from ringtrack.tools.runlog import LogWriteError
    from ringtrack.tools.views import LiveView, print_outcome, print_report

    scenario = scenario_from_arguments(args)
    model = TeamModel(scenario, args.clock)
    model.expected, model.up = startup_names(scenario), {MONITOR}
    if args.display_handover is not None:
        from ringtrack.tools.startup import started_at

        model.started = started_at(args.display_handover) or model.started  # spawn's frame counted from then
    console = Console(force_terminal=True) if args.dashboard else out
    dashboard = args.dashboard or (console.is_terminal and not args.no_dashboard)
    try:
        with LiveView(console, model, dashboard, handover=args.display_handover) as view:
            if args.connect_from is not None:
                args.connect = [*(args.connect or []), *wait_for_endpoints(args.connect_from)]
            code, report = asyncio.run(
                run_monitor(scenario, scenario.seed, args.run, bus_config(args, [MONITOR], scenario.robots),
                            args.log, scenario.max_steps, args.clock, model, view.refresh, args.exit_with_parent,
                            digests(args))
            )
    except LogWriteError as error:
        log_write_failed(error)
    if report is not None:
        # The log is complete: a second signal (the supervisor's, halfway through its grace) must not
        # cut the report short.
        for number in (signal.SIGINT, signal.SIGTERM):
            signal.signal(number, signal.SIG_IGN)
        print_report(out, report, all_robots=args.all_robots)
        outcome = run_outcome(args.log)
        if outcome is not None:
            print_outcome(out, outcome, report)
        if not report.consistent():
            err.print("monitor: warning: the traffic seen differs from what the senders counted (lost or injected "
                      "messages; see the table and the log's end record)", highlight=False)
    return finished("monitor", code)


ENDPOINTS_TIMEOUT_S = 20.0


def wait_for_endpoints(path: Path, timeout_s: float = ENDPOINTS_TIMEOUT_S) -> list[str]:
    """The endpoints announced in ``path`` (``world --announce``), waiting at most ``timeout_s``."""
    import time

    from ringtrack.bus.config import announced_endpoints

    deadline = time.monotonic() + timeout_s
    while (endpoints := announced_endpoints(path)) is None:
        if time.monotonic() > deadline:
            raise UsageError(f"--connect-from {path}: no endpoints announced within {timeout_s:.0f} s; start the "
                             "world with --announce PATH")
        time.sleep(0.02)
    return endpoints


def run_outcome(log_path: Path) -> dict | None:
    """The summary (Ctime, Com-bar, ...) of the run a log holds, None when it has no step."""
    from ringtrack.agents.engine import summary
    from ringtrack.tools.runlog import history_from_log, read_log

    log = read_log(log_path)
    return summary(history_from_log(log)) if log.steps else None


def log_write_failed(error: Exception) -> NoReturn:
    """End a monitor whose run log could not be written with ``LogWriteError.exit_code``, whatever
    becomes of its message: its standard error may be a file on the same full disk, and a failed
    flush at interpreter exit would turn the code into 120."""
    import contextlib
    import os

    from ringtrack.tools.runlog import LogWriteError

    with contextlib.suppress(OSError):
        err.print(f"monitor: {error}; stopping", highlight=False, markup=False)
    os._exit(LogWriteError.exit_code)


def finished(role: str, code: int) -> int:
    """Say why a role stops with code 1 (the world vanished without ending the run); pass the code on."""
    if code == 1:
        err.print(f"{role}: the world went away without ending the run (it crashed or was killed); stopping",
                  highlight=False)
    return code


if __name__ == "__main__":
    import sys

    from ringtrack.tools.cli import main

    sys.exit(main(commands=("roles",)))
