"""Ragged batches (teams of several sizes in one batch, agents/layout.py): the ring arithmetic and
the sums of each team are those of a uniform batch of its size, to the last bit, and a stationary
sweep run ragged (converged teams leaving the batch) equals a uniform batch per team size."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ringtrack.agents import engine
from ringtrack.agents.layout import Layout
from ringtrack.tools.studies.experiment import random_start_scenarios
from ringtrack.world.ring import midpoint_errors, predecessor_values, successor_values
from ringtrack.world.scenario import load_scenario

SERIES = ("cerr", "cerr_true", "polls", "sent_bytes", "ctime")


def assert_same(ragged: engine.TeamSeries, uniform: engine.TeamSeries) -> None:
    for name in SERIES:
        assert np.array_equal(getattr(ragged, name), getattr(uniform, name), equal_nan=True), name


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(3, 12), min_size=1, max_size=6), st.integers(0, 2**32 - 1))
def test_ragged_rings_and_sums_are_each_teams_own(sizes: list[int], seed: int) -> None:
    layout = Layout.of_teams(sizes)
    rng = np.random.default_rng(seed)
    angles = rng.uniform(-np.pi, np.pi, (1, layout.robots))
    counts = rng.integers(0, 5, (1, layout.robots, 2))
    errors = midpoint_errors(angles, layout.successor, layout.predecessor)
    sums, whole = layout.team_sum(np.abs(errors)), layout.team_sum(counts)
    first = 0
    for team, size in enumerate(sizes):
        own = angles[:, first:first + size]
        assert np.array_equal(layout.successor(angles)[:, first:first + size], successor_values(own))
        assert np.array_equal(layout.predecessor(angles)[:, first:first + size], predecessor_values(own))
        assert np.array_equal(errors[:, first:first + size], midpoint_errors(own))
        assert sums[team].tobytes() == np.add.reduce(np.abs(midpoint_errors(own)), axis=-1)[0].tobytes()
        assert np.array_equal(whole[team], counts[0, first:first + size].sum(axis=0))
        assert np.array_equal(layout.ids[0][0, first:first + size, 0], np.arange(size))
        first += size
    kept, robots = layout.keep(np.arange(len(sizes)) % 2 == 0)
    assert kept.sizes == tuple(sizes[::2])
    assert np.array_equal(angles[:, robots], np.concatenate([angles[:, sum(sizes[:team]):sum(sizes[:team + 1])]
                                                            for team in range(0, len(sizes), 2)], axis=1))


@settings(max_examples=8, deadline=None)
@given(st.lists(st.integers(3, 14), min_size=1, max_size=4, unique=True), st.integers(1, 3),
       st.sampled_from(["constant", "self", "plan"]), st.sampled_from(["prop", "deadbeat"]), st.integers(0, 500))
def test_a_ragged_sweep_equals_a_uniform_batch_per_team_size(sizes: list[int], trials: int, strategy: str, law: str,
                                                            first_seed: int) -> None:
    """Teams of several sizes (in the order given, sizes mixed) in one ragged batch whose converged
    teams leave it: each team's Cerr, true Cerr, polls and bytes per step, and its Ctime, are those
    of a uniform batch of its size (the plan strategy's teams stay to the end: its memory keeps
    every robot)."""
    by_size = {size: random_start_scenarios("paper-stationary", size, [strategy], law=law)[strategy]
               for size in sizes}
    scenarios = [by_size[size] for trial in range(trials) for size in sizes]
    seeds = [first_seed + trial for trial in range(trials) for _ in sizes]
    assert_same(engine.run_until_converged(scenarios, seeds), engine.uniform_series(scenarios, seeds))


def test_teams_leave_a_ragged_batch_once_converged() -> None:
    """A ragged batch of constant-strategy teams steps fewer robots as its teams converge, and
    ends at its last team's Ctime."""
    by_size = {size: random_start_scenarios("paper-stationary", size, ["constant"])["constant"] for size in (5, 9)}
    scenarios, seeds = [by_size[5]] * 6 + [by_size[9]] * 6, list(range(6)) * 2
    batch = engine.Batch.of_teams(scenarios, seeds, by_size[5].max_steps)
    stepped: list[int] = []
    original = batch.step

    def counting(k: int, watch: object = None) -> engine.StepRecord:
        stepped.append(batch.layout.robots)
        return original(k)

    batch.step = counting  # type: ignore[method-assign]
    series = engine._ragged_series(batch, np.rad2deg([each.threshold for each in scenarios]), by_size[5].max_steps)
    assert stepped[0] == 6 * 5 + 6 * 9 and stepped[-1] < stepped[0]
    assert len(stepped) == len(series.cerr) == series.ctime.max()
    assert_same(series, engine.uniform_series(scenarios, seeds))


@pytest.mark.parametrize(("change", "error"), [
    ({"drop": 0.2}, "a ragged batch runs without faults"),
    ({"communication_range": 8.0}, "a ragged batch runs without a communication range"),
    ({"estimation": "decentralized", "strategy": "belief"},
     "a ragged batch runs robots that know the target, with a strategy that neither listens, pushes nor relays"),
    ({"sigma_deg": 0.1}, "paper-stationary: teams of one ragged batch may differ only in [team]"),
])
def test_a_ragged_batch_refuses_what_it_cannot_run(change: dict, error: str) -> None:
    """What a ragged batch cannot run is said; run_until_converged then runs a uniform batch per
    scenario, each trial as it runs alone."""
    base = load_scenario("paper-stationary", max_steps=300)
    other = load_scenario("paper-stationary", robots=4, max_steps=300, **change)
    teams = [other, base] if "sigma_deg" in change else [other, other]
    assert engine.ragged_refusal(teams) == error
    with pytest.raises(ValueError) as raised:
        engine.Batch.of_teams(teams, [0, 1], 300)
    assert str(raised.value) == error
    scenarios, seeds = [base, base, other], [0, 1, 2]
    series = engine.run_until_converged(scenarios, seeds)
    for column, (scenario, seed) in enumerate(zip(scenarios, seeds, strict=True)):
        alone = engine.run(scenario, [seed], until_converged=True, record_positions=False)
        assert series.ctime[column] == alone.ctime[0]
        assert np.array_equal(series.cerr_true[:alone.steps, column], alone.cerr_true[:, 0])
        assert np.array_equal(series.polls[:alone.steps, column], (alone.triggers[:, 0] != 0).sum(axis=-1))


COUNTING = '''
import numpy as np
from ringtrack.agents.controller import MidpointController
from ringtrack.agents.strategy import SelfTriggered


class Counting(MidpointController):
    """The self-triggered memory, and the replies each robot has had."""

    def __init__(self, *arguments, **options):
        super().__init__(*arguments, **options)
        self.replies = np.zeros(self.own_position.shape[:-1], dtype=np.int64)

    def receive(self, predecessor, successor, predecessor_fresh=True, successor_fresh=True, *ages):
        self.replies = self.replies + np.asarray(predecessor_fresh, dtype=np.int64)
        super().receive(predecessor, successor, predecessor_fresh, successor_fresh, *ages)


class CountingReplies(SelfTriggered):
    """Self-triggered, polling once more after 50 replies."""

    name = "counting"

    def controller(self, region, params, own_position):
        return Counting(region, params, own_position, rule=self.triggers)

    def triggers(self, controller):
        reasons = super().triggers(controller)
        return np.where(controller.replies == 50, reasons | 1, reasons)
'''


def test_a_strategys_own_controller_keeps_every_robot(tmp_path) -> None:
    """A strategy file whose controller subclasses the midpoint one with state of its own runs
    ragged with its teams kept to the end (teams leaving would cut the base state only), and equals
    a uniform batch per team size."""
    strategy = tmp_path / "counting.py"
    strategy.write_text(COUNTING)
    by_size = {size: random_start_scenarios("paper-stationary", size, [str(strategy)])["counting"] for size in (3, 5, 9)}
    scenarios, seeds = [by_size[size] for _ in range(3) for size in (3, 5, 9)], [trial for trial in range(3)
                                                                                  for _ in (3, 5, 9)]
    batch = engine.Batch.of_teams(scenarios, seeds, 100)
    assert batch.layout.ragged and not batch.keeps
    with pytest.raises(ValueError, match="lets teams leave"):
        batch.keep(np.arange(len(scenarios)) > 0)
    assert_same(engine.run_until_converged(scenarios, seeds), engine.uniform_series(scenarios, seeds))
