"""Shared helpers of the test suite, in one module: independent formulas and hypothesis strategies,
scenarios written as a user would, and the helpers of tests that run teams of real processes.

The formulas and strategies are written from docs/algorithms.md, not from the code under test, so
that the tests can catch the code disagreeing with it:

* ``convex_vertices``: random strictly convex polygons (CCW vertex arrays), either points on a rotated
  ellipse at sorted random angles or the convex hull of random points, with near-degenerate ones
  (tiny edges, almost straight corners, slivers) rejected;
* ``regions`` / ``region_with_points``: a validated :class:`ConvexRegion` plus interior points (a random
  convex combination of the vertices, pulled towards the vertex centroid);
* ``ring_angles``: N angles (radians) in strict CCW cyclic order;
* ``lyapunov``, ``ccw_gaps``, ``midpoint_offsets``, ``sweep_omega``, ...: formulas written out anew;
* ``scenario_toml`` / ``scenario_from``: a scenario built from TOML text; ``short_sighted``:
  authors-moving with a limited sensing range;
* ``examples``: a property test's hypothesis example count under the active profile.

Process helpers (tests marked ``processes``): ``lockstep_run`` and ``assert_equals_engine`` (a
lockstep team equals the in-process engine), ``start_spawn`` / ``wait_for_steps`` / ``stop_all``
(``ringtrack spawn`` as a child), ``processes_mentioning`` (what is left running). The hostile
participant is a program of its own, ``python -m tests.hostile``.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import numpy as np
from hypothesis import assume
from hypothesis import strategies as st

from ringtrack.agents import engine
from ringtrack.agents.engine import History
from ringtrack.tools.runlog.log import RunLog, history_from_log, read_log
from ringtrack.tools.team.plan import TeamPlan, TeamResult
from ringtrack.tools.team.spawn import spawn_team
from ringtrack.world.geometry import ConvexRegion
from ringtrack.world.scenario import Scenario, load_scenario, parse_scenario, resolve

TWO_PI = 2.0 * math.pi

# ---------------------------------------------------------------------------- hypothesis budgets
# HYPOTHESIS_PROFILE picks how many examples every property test draws: "ci" (what `make test` and
# CI run) the counts written in the tests, "dev" (plain pytest, the edit-test loop) 30 % of them,
# "thorough" ten times as many. conftest.py registers the profiles from the same table.
EXAMPLE_SCALE = {"dev": 0.3, "ci": 1.0, "thorough": 10.0}
MIN_EXAMPLES = 10
PROFILE = os.environ.get("HYPOTHESIS_PROFILE", "dev")
if PROFILE not in EXAMPLE_SCALE:
    raise SystemExit(f"HYPOTHESIS_PROFILE={PROFILE!r}: give one of {', '.join(EXAMPLE_SCALE)}")


def examples(count: int, profile: str = PROFILE) -> int:
    """The example count of a property test written for ``count`` examples (its CI count) under
    ``profile``: scaled by :data:`EXAMPLE_SCALE`, never below :data:`MIN_EXAMPLES` (nor ``count``)."""
    return max(min(count, MIN_EXAMPLES), round(count * EXAMPLE_SCALE[profile]))


# Authors' polygon and target (docs/algorithms.md sections 10, 11, 13).
AUTHORS_VERTICES = [[3.0, 7.0], [8.0, 17.0], [5.0, 26.0], [1.0, 22.0]]
AUTHORS_TARGET = (4.0, 20.0)
PAPER_ANGLES_DEG = [69.8979, 75.0730, 83.1024, 108.1016, 170.1016, 303.8982]
# The shipped authors-moving scenario as text, and its [target] lines (to swap for another motion).
SCENARIOS = Path(__file__).resolve().parent.parent / "scenarios"
MOVING = (SCENARIOS / "authors-moving.toml").read_text()
CIRCLE_LINES = ('motion = "circle"\ncentre = [3.0, 20.0]\nspeed = 0.1            # m/s\n'
                'angular_speed = 0.1    # rad/s: 0.01 rad per step\n')


# ---------------------------------------------------------------------------- polygons
def polygon_quality_ok(vertices: np.ndarray) -> bool:
    """Reject polygons that are valid but numerically degenerate for the oracles' tolerances."""
    vertices = np.asarray(vertices, dtype=float)
    if len(vertices) < 3:
        return False
    edges = np.roll(vertices, -1, axis=0) - vertices
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    diameter = np.max(np.linalg.norm(vertices[:, None] - vertices[None], axis=-1))
    if lengths.min() < 0.02 * diameter:
        return False
    incoming = np.roll(edges, 1, axis=0)
    cross = incoming[:, 0] * edges[:, 1] - incoming[:, 1] * edges[:, 0]
    turn = np.arctan2(cross, np.einsum("kd,kd->k", incoming, edges))
    if turn.min() < 0.03:  # every corner must turn left by a visible angle (strictly convex, CCW)
        return False
    area = 0.5 * np.sum(vertices[:, 0] * np.roll(vertices[:, 1], -1) - np.roll(vertices[:, 0], -1) * vertices[:, 1])
    return area > 0.03 * diameter**2


@st.composite
def ellipse_vertices(draw: st.DrawFn) -> np.ndarray:
    count = draw(st.integers(3, 12))
    gaps = np.array(draw(st.lists(st.floats(0.2, 1.0), min_size=count, max_size=count)))
    start = draw(st.floats(0.0, TWO_PI))
    angles = start + TWO_PI * np.cumsum(gaps) / gaps.sum()
    a = draw(st.floats(0.5, 30.0))
    b = a * draw(st.floats(0.25, 1.0))
    tilt = draw(st.floats(0.0, math.pi))
    centre = np.array([draw(st.floats(-20.0, 20.0)), draw(st.floats(-20.0, 20.0))])
    local = np.stack([a * np.cos(angles), b * np.sin(angles)], axis=1)
    rotation = np.array([[math.cos(tilt), -math.sin(tilt)], [math.sin(tilt), math.cos(tilt)]])
    return centre + local @ rotation.T


@st.composite
def hull_vertices(draw: st.DrawFn) -> np.ndarray:
    from scipy.spatial import ConvexHull

    count = draw(st.integers(3, 14))
    scale = draw(st.floats(0.5, 30.0))
    coordinate = st.floats(-1.0, 1.0)
    points = np.array(draw(st.lists(st.tuples(coordinate, coordinate), min_size=count, max_size=count)))
    assume(np.linalg.matrix_rank(points - points.mean(axis=0), tol=1e-3) == 2)
    hull = ConvexHull(points)
    vertices = points[hull.vertices] * scale  # CCW in 2-D
    shift = draw(st.integers(0, len(vertices) - 1))
    offset = np.array([draw(st.floats(-20.0, 20.0)), draw(st.floats(-20.0, 20.0))])
    return np.roll(vertices, shift, axis=0) + offset


def convex_vertices() -> st.SearchStrategy[np.ndarray]:
    """CCW vertex arrays of non-degenerate strictly convex polygons."""
    return st.one_of(ellipse_vertices(), hull_vertices()).filter(polygon_quality_ok)


def regions() -> st.SearchStrategy[ConvexRegion]:
    return convex_vertices().map(ConvexRegion.from_vertices)


def interior_point(draw: st.DrawFn, vertices: np.ndarray, pull_max: float = 0.95) -> np.ndarray:
    """A convex combination of the vertices, pulled towards the vertex centroid: strictly interior."""
    weights = np.array(draw(st.lists(st.floats(0.0, 1.0), min_size=len(vertices), max_size=len(vertices))))
    weights = weights + 1e-3
    point = weights @ vertices / weights.sum()
    centroid = vertices.mean(axis=0)
    pull = draw(st.floats(0.0, pull_max))
    return centroid + pull * (point - centroid)


@st.composite
def region_with_points(
    draw: st.DrawFn, count: int = 1, pull_max: float = 0.95
) -> tuple[ConvexRegion, list[np.ndarray]]:
    region = draw(regions())
    return region, [interior_point(draw, region.vertices, pull_max) for _ in range(count)]


# ---------------------------------------------------------------------------- rings
@st.composite
def ring_angles(draw: st.DrawFn, min_robots: int = 3, max_robots: int = 30, min_weight: float = 1e-3) -> np.ndarray:
    """Angles (radians) of N robots in strict CCW order, starting anywhere: random positive gaps
    summing to 2 pi, the smallest at least ``min_weight / max weight`` of the largest."""
    robots = draw(st.integers(min_robots, max_robots))
    weights = np.array(draw(st.lists(st.floats(min_weight, 1.0), min_size=robots, max_size=robots)))
    start = draw(st.floats(-math.pi, math.pi))
    gaps = TWO_PI * weights / weights.sum()
    return start + np.concatenate([[0.0], np.cumsum(gaps[:-1])])


def lyapunov(angles: np.ndarray) -> np.ndarray:
    """H = (1/12) sum_i (d_i^+)^3 over the last axis (docs/algorithms.md section 6), gaps computed here
    independently."""
    angles = np.asarray(angles, dtype=float)
    gaps = np.mod(np.roll(angles, -1, axis=-1) - angles, TWO_PI)
    return np.sum(gaps**3, axis=-1) / 12.0


def ccw_gaps(angles: np.ndarray) -> np.ndarray:
    angles = np.asarray(angles, dtype=float)
    return np.mod(np.roll(angles, -1, axis=-1) - angles, TWO_PI)


def midpoint_offsets(angles: np.ndarray) -> np.ndarray:
    """e_i = V_i - theta_i = (d_i^+ - d_i^-)/4 (docs/algorithms.md section 2), computed independently."""
    gaps = ccw_gaps(angles)
    return (gaps - np.roll(gaps, 1, axis=-1)) / 4.0


# ---------------------------------------------------------------------------- independent geometry
def boundary_at(vertices: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Point at arc length s (CCW from vertex 0) of the closed polygon, written independently."""
    vertices = np.asarray(vertices, dtype=float)
    edges = np.roll(vertices, -1, axis=0) - vertices
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    s = np.mod(np.asarray(s, dtype=float), cumulative[-1])
    edge = np.clip(np.searchsorted(cumulative, s, side="right") - 1, 0, len(vertices) - 1)
    fraction = (s - cumulative[edge]) / lengths[edge]
    return vertices[edge] + fraction[..., None] * edges[edge]


def sweep_omega(vertices: np.ndarray, centre: np.ndarray, d_max: float, dt: float, samples: int = 200_000) -> float:
    """(1/dt) min_s wrap(theta(s + d_max) - theta(s)), docs/algorithms.md section 10, on a fine grid plus the
    vertex-aligned windows."""
    vertices = np.asarray(vertices, dtype=float)
    lengths = np.hypot(*(np.roll(vertices, -1, axis=0) - vertices).T)
    perimeter = lengths.sum()
    vertex_s = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    s = np.concatenate([np.linspace(0.0, perimeter, samples, endpoint=False), vertex_s, vertex_s - d_max])
    a = boundary_at(vertices, s) - centre
    b = boundary_at(vertices, s + d_max) - centre
    swept = np.mod(np.arctan2(b[:, 1], b[:, 0]) - np.arctan2(a[:, 1], a[:, 0]), TWO_PI)
    return float(swept.min() / dt)


def circular_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b| on the circle (radians), in [0, pi]."""
    return np.abs(np.mod(np.asarray(a) - np.asarray(b) + math.pi, TWO_PI) - math.pi)


# ---------------------------------------------------------------------------- scenarios
def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)


def scenario_toml(vertices, target, robots: int, angles_deg=None, **control: object) -> str:
    """A scenario file as a user would write it."""
    lines = [
        'name = "test"',
        "seed = 0",
        "[region]",
        f"vertices = {_toml_value([[float(x), float(y)] for x, y in np.asarray(vertices, dtype=float)])}",
        "[target]",
        f"position = {_toml_value([float(c) for c in target])}",
        "[team]",
        f"robots = {robots}",
    ]
    if angles_deg is not None:
        lines.append(f"angles_deg = {_toml_value([float(a) for a in angles_deg])}")
    lines.append("[control]")
    lines += [f"{key} = {_toml_value(value)}" for key, value in control.items()]
    return "\n".join(lines) + "\n"


def scenario_from(vertices, target, robots: int, angles_deg=None, **control: object) -> Scenario:
    text = scenario_toml(vertices, target, robots, angles_deg, **control)
    return resolve(parse_scenario(text, "test.toml"), "test.toml")


SENSING_RANGE = 3.0  # m: the authors' robots start 2.3 to 6.5 m from the target


def short_sighted(estimation: str, prior: str, **overrides: object) -> Scenario:
    """authors-moving with a sensing range of ``SENSING_RANGE`` and the given estimation and prior."""
    spec = load_scenario("authors-moving", estimation=estimation, **overrides).spec
    spec = msgspec.structs.replace(spec, sensing=msgspec.structs.replace(spec.sensing, range=SENSING_RANGE),
                                   estimation=msgspec.structs.replace(spec.estimation, prior=prior))
    return resolve(spec, "short-sighted")


# ---------------------------------------------------------------------------- teams of processes
RINGTRACK = [sys.executable, "-m", "ringtrack.tools.cli"]


def lockstep_run(scenario: Scenario, runs: Path, audit: bool = False) -> tuple[TeamResult, RunLog]:
    """Spawn a lockstep team (with ``audit``, the monitor observing every message itself) and return
    its summary and run log."""
    result = spawn_team(TeamPlan(scenario=scenario, clock="lockstep", runs=runs, dashboard=False, audit=audit))
    assert result.exit_code == 0, result
    return result, read_log(Path(result.log))


def engine_twin(log: RunLog) -> History:
    """The in-process engine run of the same scenario, seed and step count as a logged run."""
    return engine.run(log.scenario, seeds=log.header["seed"], steps=len(log.steps))


def assert_equals_engine(log: RunLog) -> History:
    """Angles to 1e-9 and every trigger mask of every robot and step equal to the engine's."""
    logged = history_from_log(log)
    twin = engine_twin(log)
    assert logged.steps == twin.steps
    assert np.max(np.abs(logged.angles - twin.angles)) < 1e-9
    assert np.array_equal(logged.triggers, twin.triggers)
    return logged


def scenario(**overrides: object) -> Scenario:
    return load_scenario("paper-stationary", **overrides)


def processes_mentioning(text: str) -> list[int]:
    """Pids of live processes whose command line contains ``text`` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (entry / "stat").read_text().split()[2]
        except OSError:
            continue
        if text in command and state != "Z":
            found.append(int(entry.name))
    return found


def command_words(pid: int) -> list[bytes]:
    """The words of process ``pid``'s command line (a robot forked by spawn's launcher sets its
    command line as one string, a started process has one word per NUL-separated argument)."""
    return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").split()


def start_spawn(runs: Path, *arguments: str) -> subprocess.Popen[bytes]:
    """``ringtrack spawn`` as a child in its own process group (so a test can signal it like a shell)."""
    return subprocess.Popen(
        [*RINGTRACK, "spawn", "--runs", str(runs), "--no-dashboard", *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )


def wait_for_steps(runs: Path, steps: int, timeout_s: float = 60.0) -> Path:
    """Wait until the single run folder under ``runs`` has a log with at least ``steps`` step records."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        logs = list(runs.glob("*/log.jsonl"))
        if logs and logs[0].read_bytes().count(b'"type":"step"') >= steps:
            return logs[0].parent
        time.sleep(0.05)
    raise AssertionError(f"no log with {steps} steps under {runs} within {timeout_s} s")


def stop_all(process: subprocess.Popen[bytes]) -> None:
    """Last-resort cleanup for a test that failed half-way: kill the spawn and its run's processes."""
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait()
