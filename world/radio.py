"""The ``[radio]`` section of a scenario: the links' loss model, energy and realtime latency.

::

    [radio]
    model = "log-distance"     # "ideal" (default) | "disk" (limits.communication_range) | "log-distance"
    tx_power_dbm = 0.0         # transmit power
    path_loss_d0_db = 40.05    # PL(d0): free space at 1 m, 2.4 GHz
    d0_m = 1.0                 # reference distance, m
    exponent = 3.0             # path-loss exponent n
    shadowing_db = 4.0         # sd of the shadowing X, dB, drawn per link and step
    sensitivity_dbm = -85.0    # receiver sensitivity S: half the packets are lost at S
    transition_db = 1.0        # width w of the logistic PER(P_r) = 1 / (1 + exp((P_r - S) / w))
    e_elec_nj_per_bit = 50.0   # first-order radio: electronics, nJ/bit (transmit and receive)
    eps_amp_pj_per_bit_m2 = 100.0  # amplifier, pJ/bit/m^2 (transmit)
    overhead_bytes = 0         # per message, added to its encoded size (headers of the link layer)
    latency_ms = 0.0           # realtime, disk or log-distance: base latency of every message
    bandwidth_kbps = 250.0     # realtime, disk or log-distance: adds 8 bytes / bandwidth

The formulas are in :mod:`bus.radio`.
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, Literal

import msgspec

from ringtrack.bus.faults import FaultPlan
from ringtrack.bus.radio import Radio
from ringtrack.world.schema import Finite, NonNegative, Positive, Spec


class RadioSpec(Spec):
    model: Literal["ideal", "disk", "log-distance"] = "ideal"
    tx_power_dbm: Finite = 0.0
    path_loss_d0_db: Finite = 40.05
    d0_m: Positive = 1.0
    exponent: Positive = 3.0
    shadowing_db: NonNegative = 4.0
    sensitivity_dbm: Finite = -85.0
    transition_db: Positive = 1.0
    e_elec_nj_per_bit: NonNegative = 50.0
    eps_amp_pj_per_bit_m2: NonNegative = 100.0
    overhead_bytes: Annotated[int, msgspec.Meta(ge=0, le=65536)] = 0
    latency_ms: NonNegative = 0.0
    bandwidth_kbps: Positive = 250.0


def with_radio(plan: FaultPlan, spec: RadioSpec, communication_range: float | None, label: str) -> FaultPlan:
    """The fault plan with the scenario's radio; the disk model needs the range it is the disk of."""
    if spec.model == "disk" and communication_range is None:
        from ringtrack.world.scenario import ScenarioError  # here: the scenario module imports this one

        raise ScenarioError(f"{label}: radio.model = 'disk' needs limits.communication_range (r_c, metres); set it")
    radio = Radio(
        model=spec.model,
        tx_power_dbm=spec.tx_power_dbm,
        path_loss_d0_db=spec.path_loss_d0_db,
        d0_m=spec.d0_m,
        exponent=spec.exponent,
        shadowing_db=spec.shadowing_db,
        sensitivity_dbm=spec.sensitivity_dbm,
        transition_db=spec.transition_db,
        e_elec=spec.e_elec_nj_per_bit * 1e-9,
        eps_amp=spec.eps_amp_pj_per_bit_m2 * 1e-12,
        overhead_bytes=spec.overhead_bytes,
        latency_s=spec.latency_ms / 1000.0,
        bandwidth_bps=spec.bandwidth_kbps * 1000.0,
    )
    return dataclasses.replace(plan, radio=radio)
