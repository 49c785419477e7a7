"""Element-wise choices that take one robot's scalars as well as a team's arrays.

The laws and the controller are written once for any leading shape: the in-process engine passes
arrays of a whole batch, a robot process the scalars of one robot. numpy's functions cost about a
microsecond a call whatever the size, most of a robot's step; these helpers decide a scalar case
in plain Python and leave arrays to numpy. The results are the same bits: a choice picks one of
the values numpy would pick, and the arithmetic around them (``+ - * /`` and comparisons) is the
same IEEE operation on a float as on an array element.

Scalars here are Python or numpy floats, ints and bools (``np.float64`` is a ``float``); no NaN
reaches the laws (angles come from ``arctan2`` of finite positions), which is where Python's
``min``/``max`` and numpy's ``minimum``/``maximum`` would differ.
"""

from __future__ import annotations

from typing import Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

SCALARS = (float, int, bool, np.bool_, np.integer, np.floating)

# An array of any leading shape, or one robot's scalar (to a type checker, ints and bools are floats).
Values: TypeAlias = NDArray[Any] | float


def choose(condition: Any, yes: Any, no: Any) -> Any:
    """``np.where(condition, yes, no)``; for a scalar ``condition``, ``yes`` or ``no`` itself."""
    if isinstance(condition, SCALARS):
        return yes if condition else no
    return np.where(condition, yes, no)


def clip(value: Any, low: Any, high: Any = None) -> Any:
    """``np.minimum(np.maximum(value, low), high)`` (``np.clip`` without its wrapper; no ``high``:
    ``np.maximum(value, low)``); for scalars, Python's ``min``/``max``, which pick the same value."""
    if isinstance(value, float) and isinstance(low, float) and isinstance(high, float | None):
        return max(value, low) if high is None else min(max(value, low), high)
    return np.maximum(value, low) if high is None else np.minimum(np.maximum(value, low), high)


def anywhere(values: Any) -> bool:
    """``bool(values.any())``, counted by ``np.count_nonzero`` (one C call: about a third of the cost
    of ``ndarray.any``, which a step asks several times to skip work no robot needs)."""
    return bool(np.count_nonzero(values))


def everywhere(values: Any) -> bool:
    """``bool(values.all())``, by ``np.count_nonzero`` (see :func:`anywhere`)."""
    return bool(np.count_nonzero(values) == np.size(values))


# Up to this many elements a reduction along the last axis is left to numpy as it is (see reduce_last).
SHORT_REDUCTION = 64


def reduce_last(ufunc: np.ufunc, values: NDArray[Any]) -> NDArray[Any]:
    """``ufunc.reduce(values, axis=-1)`` for an order-free ``ufunc`` (``np.minimum``, ``np.maximum``,
    ``np.logical_and``, ``np.logical_or``: the same values whatever order it meets them in; only
    the sign of a zero tied with a zero of the other sign may differ, as it does between numpy's own
    loops, which meet elements in different orders). numpy reduces along a short last axis (a
    robot's sides, a region's edges) row by row, at many times the cost of whole-array operations,
    so a larger array is reduced along its first axis after a copy that puts the last axis first."""
    if values.size <= SHORT_REDUCTION:
        return ufunc.reduce(values, axis=-1)
    leading = np.ascontiguousarray(values.transpose((values.ndim - 1, *range(values.ndim - 1))))
    return ufunc.reduce(leading, axis=0)


def scalar(values: Any) -> Any:
    """A 0-d array's one element as a numpy scalar (arithmetic on it skips numpy's per-call cost);
    any other array unchanged."""
    return values[()] if isinstance(values, np.ndarray) and values.ndim == 0 else values
