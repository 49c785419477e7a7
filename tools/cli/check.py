"""``ringtrack check SCENARIO``: the sizes of the region and the range bounds for the scenario's team.

Prints the perimeter L, D_in, D_out, the necessary bounds (Thm 1: r_c >= D_in sin(pi / N),
r_s >= D_in / 2), the paper's r_c >= L / N (not sufficient: docs/algorithms.md section 11), and safe
sufficient bounds for this team and target (r_c: the longest link of the best angle-uniform
configuration, over the target's path; r_s >= D_out), and each ring link of that configuration
(about the target at step 1) with its length, its loss probability under the scenario's radio
(:func:`bus.radio.loss_probability`; with a range, 1 beyond it) and the energy of one poll over it.
Exit code 1 when the scenario's ranges break a necessary bound, 0 otherwise (warnings go to
standard error).
"""

from __future__ import annotations

import argparse

import numpy as np
from rich import box
from rich.table import Table

from ringtrack.bus.messages import robot_message_bytes
from ringtrack.bus.radio import loss_probability, message_bits, receive_energy, transmit_energy
from ringtrack.tools.cli.options import add_scenario_arguments, scenario_from_arguments
from ringtrack.tools.output.console import err, show
from ringtrack.world.ranges import (
    link_lengths,
    range_bounds,
    safe_communication_range,
    uniform_link_requirement,
    uniform_ring,
)
from ringtrack.world.scenario import Scenario


def register(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser("check", help="range bounds of a scenario: what r_c and r_s must be")
    add_scenario_arguments(parser, steps_help="steps of the target path to check (default: control.max_steps)")
    parser.set_defaults(handler=run_check)


def run_check(args: argparse.Namespace) -> int:
    scenario = scenario_from_arguments(args)
    bounds = range_bounds(scenario.region, scenario.target, scenario.robots)
    safe_rc = safe_communication_range(scenario.region, scenario.target_path(scenario.seed, scenario.max_steps),
                                       scenario.robots)
    r_c = scenario.communication_range
    r_s = scenario.spec.sensing.range
    table = Table(title=f"{scenario.name}: {scenario.robots} robots, target at {scenario.target.tolist()}"
                  + (" (moving: worst over its path)" if scenario.moving else ""), box=box.SIMPLE_HEAD,
                  title_justify="left")
    for column in ("quantity", "metres", "what it means"):
        table.add_column(column, justify="right" if column == "metres" else "left")
    rows = [
        ("perimeter L", bounds.perimeter, ""),
        ("D_in", bounds.inner_diameter, "diameter of the largest inscribed disc"),
        ("D_out", bounds.outer_diameter, "longest segment in the region"),
        ("r_c >= D_in sin(pi/N)", bounds.necessary_communication, "necessary for any target (Thm 1)"),
        ("r_c >= L/N", bounds.paper_communication, "the paper's Thm 2: NOT sufficient"),
        ("r_c >= uniform link", safe_rc, "safe for this team and target path"),
        ("r_c >= D_out", bounds.outer_diameter, "safe for any target"),
        ("r_s >= D_in/2", bounds.necessary_sensing, "necessary for sensing (Thm 1)"),
        ("r_s >= D_out", bounds.safe_sensing, "sufficient for sensing"),
    ]
    for name, value, meaning in rows:
        table.add_row(name, f"{value:.4f}", meaning)
    table.add_row("scenario r_c", "unlimited" if r_c is None else f"{r_c:.4f}", "limits.communication_range")
    table.add_row("scenario r_s", "unlimited" if r_s is None else f"{r_s:.4f}", "sensing.range")
    show(table)
    show(link_table(scenario))
    broken = False
    if r_c is not None and r_c < bounds.necessary_communication:
        broken = True
        err.print(f"error: limits.communication_range {r_c:g} m is below the necessary "
                  f"{bounds.necessary_communication:.4f} m: no uniform spacing keeps the ring connected")
    elif r_c is not None and r_c < safe_rc:
        err.print(f"warning: limits.communication_range {r_c:g} m is below the {safe_rc:.4f} m the uniform "
                  "configuration needs for this target: the team cannot spread evenly and stay connected")
    if r_s is not None and r_s < bounds.necessary_sensing:
        broken = True
        err.print(f"error: sensing.range {r_s:g} m is below the necessary {bounds.necessary_sensing:.4f} m")
    elif r_s is not None and r_s < bounds.safe_sensing:
        err.print(f"warning: sensing.range {r_s:g} m is below D_out = {bounds.safe_sensing:.4f} m: "
                  "some robots may get no range")
    return 1 if broken else 0


def link_table(scenario: Scenario) -> Table:
    """Each ring link ``i -> i + 1`` of the best angle-uniform configuration about the target at
    step 1: its length, its loss probability and the radio energy of one poll over it (request and
    reply, sent and received, at step 1000)."""
    radio, robots = scenario.faults.radio, scenario.robots
    rotation = uniform_link_requirement(scenario.region, scenario.target, robots)[1]
    lengths = link_lengths(uniform_ring(scenario.region, scenario.target, robots, rotation))
    loss = loss_probability(radio, lengths)
    if scenario.communication_range is not None:
        loss = np.where(lengths > scenario.communication_range, 1.0, loss)
    belief = scenario.estimation.mode == "decentralized"
    bits = [message_bits(radio, robot_message_bytes(kind, 1000, 0, 1, belief)) for kind in ("request", "reply")]
    model = radio.model + ("" if scenario.communication_range is None else
                           f", r_c = {scenario.communication_range:g} m")
    table = Table(title=f"ring links of the uniform configuration, radio {model}", box=box.SIMPLE_HEAD,
                  title_justify="left")
    for column in ("link", "metres", "loss probability", "poll energy (J)"):
        table.add_column(column, justify="right")
    for robot, (length, lost) in enumerate(zip(lengths, loss, strict=True)):
        poll = sum(float(transmit_energy(radio, k, length) + receive_energy(radio, k)) for k in bits)
        table.add_row(f"{robot}-{(robot + 1) % robots}", f"{length:.4f}", f"{lost:.4g}", f"{poll:.3e}")
    return table
