"""The radio of robot-to-robot links: when a message is lost with distance, what it costs in energy
and, in realtime, how long it is on the air. Pure functions of a :class:`Radio`; distances are
metres, powers dBm, losses dB, energies joules, times seconds.

Loss (``model``):

* ``ideal``: distance never loses a message;
* ``disk``: a link is up when its robots are within the communication range r_c (applied by the
  range check of the fault layer's callers, as without a radio section);
* ``log-distance``: path loss ``PL(d) = PL(d0) + 10 n log10(d / d0) + X`` with shadowing
  ``X ~ N(0, shadowing_db^2)`` drawn per link and step from the fault plan's keyed hash; received
  power ``P_r = P_tx - PL(d)``; the packet error rate is the logistic in dB
  ``PER(P_r) = 1 / (1 + exp((P_r - S) / w))`` with receiver sensitivity ``S`` and transition width
  ``w``: 1/2 at the sensitivity, 0.047 at ``S + 3 w``, 0.953 at ``S - 3 w``. A message is lost when
  its own keyed uniform draw is below its PER.

Energy: the first-order radio model. Sending ``k`` bits over ``d`` metres costs
``E_elec k + eps_amp k d^2``, receiving them ``E_elec k``; ``k = 8 (payload bytes + overhead_bytes)``.

Realtime latency of a message: ``latency_s + 8 bytes / bandwidth_bps``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, TypeVar, overload

import msgspec
import numpy as np
from numpy.typing import ArrayLike, NDArray

RadioModel = Literal["ideal", "disk", "log-distance"]
QUADRATURE_NODES = 200  # Gauss-Hermite nodes of the expected loss over shadowing (w = 1 dB, sd = 3 dB: to 1e-11)


@dataclass(frozen=True)
class Radio:
    """Parameters of the links' radio (SI units; powers in dBm, losses in dB)."""

    model: RadioModel = "ideal"
    tx_power_dbm: float = 0.0
    path_loss_d0_db: float = 40.05  # free space at 1 m, 2.4 GHz
    d0_m: float = 1.0
    exponent: float = 3.0
    shadowing_db: float = 4.0
    sensitivity_dbm: float = -85.0
    transition_db: float = 1.0
    e_elec: float = 50e-9  # J/bit
    eps_amp: float = 100e-12  # J/bit/m^2
    overhead_bytes: int = 0
    latency_s: float = 0.0
    bandwidth_bps: float = 250e3

    @property
    def lossy(self) -> bool:
        """Whether distance decides a message's fate in the fault plan (the log-distance model)."""
        return self.model == "log-distance"


IDEAL = Radio()


def path_loss_db(radio: Radio, distance: ArrayLike, shadow_db: ArrayLike = 0.0) -> NDArray[np.float64]:
    """``PL(d0) + 10 n log10(d / d0) + shadow`` (dB); distances below ``d0`` count as ``d0``."""
    metres = np.maximum(np.asarray(distance, dtype=float), radio.d0_m)
    return radio.path_loss_d0_db + 10.0 * radio.exponent * np.log10(metres / radio.d0_m) + np.asarray(shadow_db)


def packet_error_rate(radio: Radio, received_dbm: ArrayLike) -> NDArray[np.float64]:
    """The logistic in dB: ``1 / (1 + exp((P_r - S) / w))``."""
    margin = (np.asarray(received_dbm, dtype=float) - radio.sensitivity_dbm) / radio.transition_db
    return 0.5 * (1.0 - np.tanh(0.5 * margin))  # = 1 / (1 + exp(margin)), without overflow


def message_loss(radio: Radio, distance: ArrayLike, shadow_db: ArrayLike) -> NDArray[np.float64]:
    """The PER of a message over ``distance`` metres under the link's shadowing draw (dB)."""
    return packet_error_rate(radio, radio.tx_power_dbm - path_loss_db(radio, distance, shadow_db))


def loss_probability(radio: Radio, distance: ArrayLike) -> NDArray[np.float64]:
    """The probability that a message over ``distance`` metres is lost by the radio: the PER
    averaged over the shadowing ``N(0, shadowing_db^2)`` (Gauss-Hermite quadrature); 0 unless the
    model is log-distance."""
    distance = np.asarray(distance, dtype=float)
    if not radio.lossy:
        return np.zeros_like(distance)
    nodes, weights = np.polynomial.hermite_e.hermegauss(QUADRATURE_NODES)
    shadows = radio.shadowing_db * nodes
    per = message_loss(radio, distance[..., None], shadows)
    return (per * weights).sum(axis=-1) / weights.sum()


Bits = TypeVar("Bits", int, NDArray[np.int64])


def message_bits(radio: Radio, payload_bytes: Bits) -> Bits:
    """Bits on the air of messages of ``payload_bytes`` (their encoded size, an int or an integer
    array) plus the overhead. Plain numbers stay plain: a robot computes one message at a time, the
    engine a whole batch, with the same operations (so the two agree to the last bit)."""
    return 8 * (payload_bytes + radio.overhead_bytes)


@overload
def transmit_energy(radio: Radio, bits: int, distance: float) -> float: ...
@overload
def transmit_energy(radio: Radio, bits: NDArray[np.int64],
                    distance: float | NDArray[np.float64]) -> NDArray[np.floating[Any]]: ...
def transmit_energy(radio: Radio, bits: int | NDArray[np.int64],
                    distance: float | NDArray[np.float64]) -> float | NDArray[np.floating[Any]]:
    """``E_elec k + eps_amp k d^2`` joules to send ``k`` bits over ``d`` metres (numbers or arrays,
    broadcast)."""
    energy: float | NDArray[np.floating[Any]] = radio.e_elec * bits + radio.eps_amp * bits * (distance * distance)
    return energy


@overload
def receive_energy(radio: Radio, bits: int) -> float: ...
@overload
def receive_energy(radio: Radio, bits: NDArray[np.int64]) -> NDArray[np.floating[Any]]: ...
def receive_energy(radio: Radio, bits: int | NDArray[np.int64]) -> float | NDArray[np.floating[Any]]:
    """``E_elec k`` joules to receive ``k`` bits."""
    return radio.e_elec * bits


def airtime_s(radio: Radio, payload_bytes: int) -> float:
    """Realtime latency of one message: ``latency_s + 8 bytes / bandwidth_bps`` (overhead included)."""
    return radio.latency_s + float(message_bits(radio, payload_bytes)) / radio.bandwidth_bps


class EnergyReport(msgspec.Struct, frozen=True):
    """The radio energy of a run's robot-to-robot traffic, joules: per robot (robot index order) to
    transmit, to receive and their sum, and the team's total."""

    per_robot_j: list[float]
    transmit_j: list[float]
    receive_j: list[float]
    team_j: float


def energy_report(transmit_j: ArrayLike, receive_j: ArrayLike) -> EnergyReport:
    """The :class:`EnergyReport` of robots that spent ``transmit_j`` and ``receive_j`` (joules, per robot)."""
    transmit, receive = np.asarray(transmit_j, dtype=float), np.asarray(receive_j, dtype=float)
    return EnergyReport(per_robot_j=(transmit + receive).tolist(), transmit_j=transmit.tolist(),
                        receive_j=receive.tolist(), team_j=float((transmit + receive).sum()))
