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
Point = tuple[Finite, Finite]


class Spec(msgspec.Struct, forbid_unknown_fields=True, kw_only=True, frozen=True, omit_defaults=True):
    """A section of a scenario file: unknown keys are refused, defaults are omitted when written."""
