"""Building blocks of the scenario schema: a strict msgspec struct base and checked number types."""

from __future__ import annotations

from typing import Annotated

import msgspec

# msgspec bounds must be finite; these also refuse NaN and infinities ("expected a finite number").
HUGE = 1e300
Finite = Annotated[float, msgspec.Meta(ge=-HUGE, le=HUGE)]
Positive = Annotated[float, msgspec.Meta(gt=0.0, le=HUGE)]
NonNegative = Annotated[float, msgspec.Meta(ge=0.0, le=HUGE)]
Probability = Annotated[float, msgspec.Meta(ge=0.0, le=1.0)]
# Positions are metres within +-1e6 of the origin: geometry stays well conditioned, and every
# position fits the bus's checked wire values (bus/messages.py).
COORDINATE_LIMIT = 1e6
Coordinate = Annotated[float, msgspec.Meta(ge=-COORDINATE_LIMIT, le=COORDINATE_LIMIT)]
Point = tuple[Coordinate, Coordinate]


class Spec(msgspec.Struct, forbid_unknown_fields=True, kw_only=True, frozen=True, omit_defaults=True):
    """A section of a scenario file: unknown keys are refused, defaults are omitted when written."""
