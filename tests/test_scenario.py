"""Scenario validation (world/scenario*.py): every refusal of a scenario file, an override or a
command-line flag is one line naming the key (or flag) and the fix, and each message is asserted
exactly here through one helper, :func:`scenario_error`."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from ringtrack.tools.cli import build_parser
from ringtrack.tools.cli.options import flag, scenario_from_arguments
from ringtrack.world.scenario import (
    OverrideError,
    ScenarioError,
    load_scenario,
    parse_scenario,
    resolve,
    shipped_scenarios,
)
from tests.helpers import (
    AUTHORS_TARGET,
    AUTHORS_VERTICES,
    CIRCLE_LINES,
    MOVING,
    RINGTRACK,
    TWO_PI,
    ccw_gaps,
    scenario_toml,
)

BASE = scenario_toml(AUTHORS_VERTICES, AUTHORS_TARGET, 6, None, dt=0.1)


def scenario_error(text: str, label: str = "x.toml") -> str:
    """The one-line message with which ``text`` (a scenario file named ``label``) is refused."""
    with pytest.raises(ScenarioError) as raised:
        resolve(parse_scenario(text, label), label)
    message = str(raised.value)
    assert "\n" not in message
    return message


def with_team(line: str) -> str:
    return BASE.replace("robots = 6", f"robots = 6\n{line}")


def with_target(lines: str) -> str:
    assert CIRCLE_LINES in MOVING
    return MOVING.replace(CIRCLE_LINES, lines)


def with_estimation(key: str, value: str) -> str:
    head, estimation = MOVING.split("[estimation]\n")
    line = next(line for line in estimation.splitlines() if line.startswith(f"{key} = "))
    return head + "[estimation]\n" + estimation.replace(line, f"{key} = {value}")


# ---------------------------------------------------------------------------- [region], [team], [control]
@pytest.mark.parametrize(
    ("text", "message"),
    [
        pytest.param(
            BASE.replace('name = "test"', 'name = "test"\nfoo = 1'),
            "x.toml: unknown key 'foo' in top level; allowed keys: region, target, name, seed, team, strategy, control, sensing, "
            "estimation, limits, faults, radio",
            id="unknown-top-level-key",
        ),
        pytest.param(
            BASE + "speed = 3\n",
            "x.toml: unknown key 'speed' in [control]; allowed keys: "
            "law, dt, omega_max_deg, v_max, sigma_deg, threshold_deg, max_steps; a strategy's own parameters go in "
            "[strategy]",
            id="unknown-control-key",
        ),
        pytest.param(
            BASE.replace("dt = 0.1", 'dt = "fast"'),
            "x.toml: control.dt: expected `float`, got `str`; fix the value",
            id="wrong-type",
        ),
        pytest.param(
            BASE.replace("robots = 6", "robots = 6.5"),
            "x.toml: team.robots: expected `int`, got `float`; fix the value",
            id="wrong-type-int",
        ),
        pytest.param(
            BASE + 'law = "lazy"\n',
            "x.toml: control.law: invalid enum value 'lazy'; use one of 'prop', 'deadbeat'",
            id="bad-choice",
        ),
        pytest.param(
            BASE.replace("[3.0, 7.0]", "[nan, 7.0]"),
            "x.toml: region.vertices[0][0]: expected a coordinate in metres within +-1,000,000; fix the value",
            id="nan-vertex",
        ),
        pytest.param(
            BASE.replace("[4.0, 20.0]", "[4.0, nan]"),
            "x.toml: target.position[1]: expected a coordinate in metres within +-1,000,000; fix the value",
            id="nan-target",
        ),
        pytest.param(
            BASE + "omega_max_deg = inf\n",
            "x.toml: control.omega_max_deg: expected a finite number; fix the value",
            id="infinite-omega",
        ),
        pytest.param(
            BASE.replace("dt = 0.1", "dt = -0.1"),
            "x.toml: control.dt: expected a finite number > 0; fix the value",
            id="negative-dt",
        ),
        pytest.param(
            BASE.replace("robots = 6", "robots = 2"),
            "x.toml: team.robots: expected `int` >= 3; fix the value",
            id="two-robots",
        ),
        pytest.param(
            BASE.replace("[4.0, 20.0]", "[40.0, 20.0]"),
            "x.toml: target.position [40.0, 20.0] is not inside the region; move it inside the polygon",
            id="target-outside",
        ),
        pytest.param(
            BASE.replace("[3.0, 7.0], [8.0, 17.0], [5.0, 26.0], [1.0, 22.0]", "[0, 0], [4, 0], [1, 1], [0, 4]").replace(
                "[4.0, 20.0]", "[0.5, 0.5]"
            ),
            "x.toml: region is not convex at vertex 2 [1.0, 1.0]; give a convex polygon",
            id="non-convex-region",
        ),
        pytest.param(
            with_team("angles_deg = [0, 60, 120]"),
            "x.toml: team.angles_deg has 3 angles for team.robots = 6; give one angle per robot",
            id="wrong-number-of-angles",
        ),
        pytest.param(
            with_team("angles_deg = [0, 60, 120, 120, 240, 300]"),
            "x.toml: team.angles_deg has co-located robots; give distinct angles",
            id="co-located",
        ),
        pytest.param(
            with_team("angles_deg = [0, 60, 120, 180, 240, 360]"),
            "x.toml: team.angles_deg has co-located robots; give distinct angles",
            id="co-located-across-360",
        ),
        pytest.param(
            with_team("angles_deg = [0, 120, 60, 180, 240, 300]"),
            "x.toml: team.angles_deg must go once counter-clockwise around the target; sort them",
            id="not-counter-clockwise",
        ),
        pytest.param(
            with_team("angles_deg = [300, 240, 180, 120, 60, 0]"),
            "x.toml: team.angles_deg must go once counter-clockwise around the target; sort them",
            id="clockwise",
        ),
        pytest.param(
            BASE.replace("[region]\n", "").replace(
                "vertices = [[3.0, 7.0], [8.0, 17.0], [5.0, 26.0], [1.0, 22.0]]\n", ""),
            "x.toml: region is missing; add it",
            id="missing-region",
        ),
    ],
)
def test_scenario_validation_messages(text, message):
    assert scenario_error(text) == message


def test_scenario_nan_in_positive_key_names_the_key():
    # NaN in a key with a positive bound is reported as "expected `float` > 0.0": it names the key,
    # though not the NaN (see report).
    assert scenario_error(BASE.replace("dt = 0.1", "dt = nan")).startswith("x.toml: control.dt: ")
    assert scenario_error(BASE + "sigma_deg = nan\n").startswith("x.toml: control.sigma_deg: ")


def test_scenario_valid_base_resolves():
    scenario = resolve(parse_scenario(BASE, "x.toml"), "x.toml")
    assert scenario.robots == 6
    assert math.degrees(scenario.threshold) == pytest.approx(0.6, rel=1e-12)
    assert math.degrees(scenario.control.omega_max) == pytest.approx(1.0, rel=1e-12)
    angles = scenario.start_angles(3)
    assert np.all(ccw_gaps(angles) > 1e-6) and ccw_gaps(angles).sum() == pytest.approx(TWO_PI)
    np.testing.assert_array_equal(angles, scenario.start_angles(3))  # seeded


# ---------------------------------------------------------------------------- [target], [sensing], [estimation]
@pytest.mark.parametrize(
    ("text", "message"),
    [
        pytest.param(
            with_target('motion = "circle"\ncentre = [3.0, 20.0]\nspeed = 0.2\nangular_speed = 0.1\n'),
            "x.toml: target circle of radius 2 m (speed / angular_speed) about [3.0, 20.0] leaves the region "
            "(1.718 m of room); lower target.speed or raise the size of target.angular_speed",
            id="circle-leaves-region",
        ),
        pytest.param(
            with_target('motion = "circle"\ncentre = [30.0, 20.0]\nspeed = 0.1\nangular_speed = 0.1\n'),
            "x.toml: target.centre [30.0, 20.0] is not inside the region; move it inside the polygon",
            id="circle-centre-outside",
        ),
        pytest.param(
            with_target('motion = "circle"\ncentre = [3.0, 20.0]\nspeed = 0.1\nangular_speed = 0.0\n'),
            "x.toml: target.angular_speed is 0 (an infinite circle); give a nonzero rad/s",
            id="circle-zero-angular-speed",
        ),
        pytest.param(
            with_target('motion = "circle"\ncentre = [3.0, 20.0]\nspeed = -0.1\nangular_speed = 0.1\n'),
            "x.toml: target.speed: expected a finite number > 0; fix the value",
            id="circle-negative-speed",
        ),
        pytest.param(
            with_target('motion = "circle"\ncentre = [3.0, 20.0]\nangular_speed = 0.1\n'),
            "x.toml: target.speed is missing; add it",
            id="circle-missing-speed",
        ),
        pytest.param(
            with_target('motion = "waypoints"\nwaypoints = [[4.0, 20.0], [40.0, 20.0]]\nspeed = 1.0\n'),
            "x.toml: target.waypoints[1] [40.0, 20.0] is not inside the region; move it inside the polygon",
            id="waypoint-outside",
        ),
        pytest.param(
            with_target('motion = "random_walk"\nposition = [0.0, 0.0]\nspeed_std = 1.0\n'),
            "x.toml: target.position [0.0, 0.0] is not inside the region; move it inside the polygon",
            id="random-walk-start-outside",
        ),
        pytest.param(
            with_target('motion = "spiral"\ncentre = [3.0, 20.0]\n'),
            "x.toml: target.motion: invalid value 'spiral'; use one of 'stationary', 'circle', 'random_walk', "
            "'waypoints'",
            id="unknown-motion",
        ),
        pytest.param(
            with_target('motion = "circle"\ncentre = [3.0, 20.0]\nspeed = 0.1\nangular_speed = 0.1\nradius = 1.0\n'),
            "x.toml: unknown key 'radius' in [target]; allowed keys: motion, centre, speed, angular_speed, phase_deg",
            id="unknown-circle-key",
        ),
        pytest.param(
            with_target('motion = "waypoints"\nwaypoints = [[4.0, 20.0], [4.0, 21.0]]\nspeed = 1.0\n'
                        'centre = [1.0, 1.0]\n'),
            "x.toml: unknown key 'centre' in [target]; allowed keys: motion, waypoints, speed, loop",
            id="unknown-waypoints-key",
        ),
        pytest.param(
            with_estimation("mode", '"known"'),
            "x.toml: estimation.mode = 'known' needs a stationary target; use 'centralized' or 'decentralized'",
            id="known-with-moving-target",
        ),
        pytest.param(
            with_estimation("prior", '"trilateration"'),
            "x.toml: estimation.prior = 'trilateration' needs the centralized mode (one robot has one range);"
            " use 'truth' or [x, y]",
            id="trilateration-decentralized",
        ),
        pytest.param(
            with_estimation("prior", "[40.0, 20.0]"),
            "x.toml: estimation.prior [40.0, 20.0] is not inside the region; move it inside the polygon",
            id="prior-outside",
        ),
        pytest.param(
            with_estimation("mode", '"psychic"'),
            "x.toml: estimation.mode: invalid enum value 'psychic'; use one of 'known', 'centralized', 'decentralized'",
            id="unknown-mode",
        ),
        pytest.param(
            MOVING.replace("range_sigma = 0.2\n\n[estimation]", "range_sigma = -0.2\n\n[estimation]"),
            "x.toml: sensing.range_sigma: expected a finite number >= 0; fix the value",
            id="negative-sensing-sigma",
        ),
    ],
)
def test_scenario_refusals(text, message):
    assert scenario_error(text) == message


def test_scenario_accepts_the_shipped_moving_scenarios_and_variants():
    for name in ("authors-moving", "gazebo-moving"):
        scenario = load_scenario(name)
        assert scenario.moving
        assert scenario.estimation.mode == "decentralized"
        assert scenario.estimation.range_sigma == 0.2 and scenario.estimation.process_noise == 0.2
        assert scenario.spec.sensing.range_sigma == 0.2
    # a prior point inside, trilateration with the centralized mode, a circle with just enough room
    inside = resolve(parse_scenario(with_estimation("prior", "[4.5, 19.0]"), "x.toml"), "x.toml")
    assert inside.estimation.prior == (4.5, 19.0)
    text = with_estimation("prior", '"trilateration"').replace('mode = "decentralized"', 'mode = "centralized"')
    assert resolve(parse_scenario(text, "x.toml"), "x.toml").estimation.prior == "trilateration"
    tight = with_target('motion = "circle"\ncentre = [3.0, 20.0]\nspeed = 0.17\nangular_speed = 0.1\n')  # r 1.7 < 1.718
    assert resolve(parse_scenario(tight, "x.toml"), "x.toml").moving


# ---------------------------------------------------------------------------- [faults], and a square region
BAD_SCENARIOS = {
    "wrong type": ('[team]\nrobots = "six"\n', "team.robots: expected `int`, got `str`; fix the value"),
    "unknown key": ("[control]\nspeed = 3\n", "unknown key 'speed' in [control]; allowed keys: law, dt, "
                    "omega_max_deg, v_max, sigma_deg, threshold_deg, max_steps; a strategy's own parameters go in "
                    "[strategy]"),
    "non-convex": (None, "region is not convex at vertex 2 [1.0, 1.0]; give a convex polygon"),
    "target outside": ("position = [9.0, 9.0]",
                       "target.position [9.0, 9.0] is not inside the region; move it inside the polygon"),
    "fewer than 3 robots": ("[team]\nrobots = 2\n", "team.robots: expected `int` >= 3; fix the value"),
    "co-located starts": ("[team]\nangles_deg = [10.0, 10.0, 200.0]\nrobots = 3\n",
                          "team.angles_deg has co-located robots; give distinct angles"),
    "NaN": ("[control]\ndt = nan\n", "control.dt: expected a finite number > 0; fix the value"),
    "negative": ("[control]\nsigma_deg = -1.0\n", "control.sigma_deg: expected a finite number >= 0; fix the value"),
    "drop above 1": ("[faults]\ndrop = 1.5\n", "faults.drop: expected a probability in [0, 1]; fix the value"),
    "negative drop": ("[faults]\ndrop = -0.1\n", "faults.drop: expected a probability in [0, 1]; fix the value"),
    "too many robots": ("[team]\nrobots = 10000000000000\n", "team.robots: expected `int` <= 100000; fix the value"),
    "huge coordinate": ('[sensing]\nrange = 1.0\n[estimation]\nmode = "centralized"\nprior = [1e300, 0.0]\n',
                        "estimation.prior[0]: expected a coordinate in metres within +-1,000,000; fix the value"),
    "outage robot": ("[[faults.outages]]\nlinks = [[0, 7]]\nfrom_step = 1\nto_step = 5\n",
                     "faults.outages[0].links [0, 7] must name two different robots 0..5"),
    "outage self-link": ("[[faults.outages]]\nlinks = [[2, 2]]\nfrom_step = 1\nto_step = 5\n",
                         "faults.outages[0].links [2, 2] must name two different robots 0..5"),
    "outage backwards": ("[[faults.outages]]\nlinks = [[0, 1]]\nfrom_step = 9\nto_step = 5\n",
                         "faults.outages[0] ends before it starts; give from <= to"),
    "outage without links": ("[[faults.outages]]\nlinks = []\nfrom_step = 1\nto_step = 5\n",
                             "faults.outages[0].links is empty; name the links that go down, e.g. [[0, 1]]"),
    "outage in steps and seconds": ("[[faults.outages]]\nlinks = [[0, 1]]\nfrom_step = 1\nto_step = 5\nfrom_s = 1.0\n"
                                    "to_s = 2.0\n",
                                    "faults.outages[0] needs from_step and to_step, or from_s and to_s "
                                    "(simulated seconds)"),
    "link override to itself": ("[[faults.links]]\nbetween = [3, 3]\ndrop = 0.5\n",
                                "faults.links[0].between [3, 3] must name two different robots 0..5"),
}
GOOD = """name = "bad"
[region]
vertices = [[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]]
[target]
position = [1.0, 1.0]
"""


def bad_scenario(case: str) -> str:
    """The square scenario ``GOOD`` with the change of ``BAD_SCENARIOS[case]``."""
    addition, _ = BAD_SCENARIOS[case]
    if case == "non-convex":
        return GOOD.replace("[[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]]", "[[0, 0], [4, 0], [1, 1], [0, 4]]")
    if case == "target outside":
        return GOOD.replace("position = [1.0, 1.0]", addition)
    return GOOD + addition


@pytest.mark.parametrize("case", list(BAD_SCENARIOS))
def test_bad_scenarios_are_refused_in_one_line(case: str) -> None:
    assert scenario_error(bad_scenario(case)) == f"x.toml: {BAD_SCENARIOS[case][1]}"


@pytest.mark.processes
@pytest.mark.parametrize("case", ["wrong type", "non-convex", "outage robot"])  # decoding, geometry, fault plan
def test_bad_scenarios_get_one_line_and_exit_code_2(tmp_path: Path, case: str) -> None:
    text = bad_scenario(case)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    for command in ("simulate", "spawn", "check"):
        completed = subprocess.run([*RINGTRACK, command, str(path)], capture_output=True, text=True, timeout=60)
        assert completed.returncode == 2
        assert completed.stderr.strip().splitlines() == [f"ringtrack: error: {scenario_error(text, str(path))}"]


# ---------------------------------------------------------------------------- names and overrides
def test_unknown_shipped_scenario_name():
    with pytest.raises(ScenarioError) as raised:
        load_scenario("no-such-scenario")
    assert str(raised.value) == (
        "scenario 'no-such-scenario' is neither a file nor a shipped scenario; use a path or one of: "
        + ", ".join(shipped_scenarios())
    )
    assert {"paper-stationary", "authors-quadrilateral"} <= set(shipped_scenarios())


def test_override_errors():
    with pytest.raises(ScenarioError) as raised:
        load_scenario("paper-stationary", speed=3)
    assert str(raised.value).startswith("unknown override 'speed'; use one of strategy, law, dt,")
    with pytest.raises(OverrideError) as raised:
        load_scenario("paper-stationary", dt=-1.0)
    assert str(raised.value) == "control.dt: expected a finite number > 0; fix the value"
    assert (raised.value.name, raised.value.value, raised.value.path) == ("dt", -1.0, "control.dt")


def test_override_errors_on_the_command_line_name_the_flag():
    args = build_parser().parse_args(["simulate", "--robots", "2"])
    with pytest.raises(ScenarioError) as raised:
        scenario_from_arguments(args)
    assert str(raised.value) == "--robots 2 (team.robots): expected `int` >= 3; fix the value"
    assert (flag("max_steps"), flag("sigma_deg"), flag("drop")) == ("--steps", "--sigma-deg", "--drop")
