"""What one trial of a run came to: :class:`RunSummary`, made by :func:`summarise` from a history.

The in-process engine (``ringtrack simulate``), a team of processes (``ringtrack spawn``, from its run
log) and the monitor's end-of-run report all summarise a run with this one function, so a figure
such as Ctime or Com-bar means the same wherever it is shown. Angles in degrees, distances in metres,
energy in joules; steps are counted from 1.
"""

from __future__ import annotations

import msgspec
import numpy as np

from ringtrack.agents.engine import History, fault_totals
from ringtrack.agents.strategy import strategy_for
from ringtrack.bus.radio import EnergyReport, energy_report
from ringtrack.world.metrics import settled_mean

SETTLE_STEPS = 300  # moving targets: Cerr and Terr means leave out the first steps (as experiment moving)


class Polls(msgspec.Struct, frozen=True):
    """How often the robots polled their neighbours over a run."""

    total: int
    per_robot: list[int]  # robot index order (counter-clockwise)


class RunSummary(msgspec.Struct, frozen=True, omit_defaults=True):
    """One trial of a run: convergence, communication and error (the JSON of ``simulate --json``).

    ``ctime`` is the paper's Ctime (the first step from which the strategy's Cerr stays below
    ``threshold_deg``; None: not converged), ``ctime_true`` the same on the true Cerr, ``com_bar``
    polls per robot per step up to Ctime (the constant strategy's is 1; None unless converged).
    ``robot_messages`` counts every robot-to-robot message put on the bus (requests, replies,
    pushes). ``terr_mean`` is the mean target error (metres) over every step of a stationary
    target; for a moving one it and ``cerr_mean_deg`` (true Cerr) leave out the steps before
    ``from_step``. ``robot_bytes`` and ``energy`` are there when the history counted bytes."""

    scenario: str
    strategy: str
    law: str
    robots: int
    seed: int
    steps: int
    threshold_deg: float
    converged: bool
    ctime: int | None
    ctime_true: int | None
    com_bar: float | None
    triggers: Polls
    cerr_final_deg: float | None
    cerr_true_final_deg: float
    estimation: str
    terr_mean: float | None
    terr_final: float
    robot_messages: int
    faults: dict[str, int]
    from_step: int | None = None
    cerr_mean_deg: float | None = None
    robot_bytes: int | None = None
    energy: EnergyReport | None = None


def summarise(history: History, trial: int = 0, settle: int = SETTLE_STEPS) -> RunSummary:
    """The summary of trial ``trial`` of ``history``; a moving target's means leave out the first
    ``settle`` steps (:func:`world.metrics.settled_mean`)."""
    scenario = history.scenario
    ctime = int(history.ctime[trial])
    ctime_true = int(history.ctime_true[trial])
    polled = (history.triggers[:, trial] != 0).sum(axis=0)
    counted = history.energy is not None and history.sent_bytes is not None
    return RunSummary(
        scenario=scenario.name,
        strategy=strategy_for(scenario.strategy).name,
        law=scenario.control.law,
        robots=int(history.angles.shape[2]),
        seed=history.seeds[trial],
        steps=history.steps,
        threshold_deg=float(np.rad2deg(scenario.threshold)),
        converged=ctime > 0,
        ctime=ctime or None,
        ctime_true=ctime_true or None,
        com_bar=float(history.com_bar[trial]) if ctime else None,
        triggers=Polls(int(polled.sum()), polled.tolist()),
        cerr_final_deg=_known(history.cerr[-1, trial]),
        cerr_true_final_deg=float(history.cerr_true[-1, trial]),
        estimation=scenario.estimation.mode,
        terr_mean=settled_mean(history.terr[:, trial], settle) if scenario.moving
        else float(history.terr[:, trial].mean()),
        terr_final=float(history.terr[-1, trial]),
        robot_messages=int(history.sent[:, trial].sum()),
        faults=fault_totals(history, trial),
        from_step=settle if scenario.moving else None,
        cerr_mean_deg=settled_mean(history.cerr_true[:, trial], settle) if scenario.moving else None,
        robot_bytes=int(history.sent_bytes[:, trial].sum()) if counted else None,  # type: ignore[index]
        energy=energy_report(*history.energy[:, trial].sum(axis=0).T) if counted else None,  # type: ignore[index]
    )


def _known(value: float) -> float | None:
    """A figure for JSON: None where it is unknown (NaN)."""
    return None if np.isnan(value) else float(value)
