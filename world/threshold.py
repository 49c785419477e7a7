"""What a convergence threshold means for a team of a given size.

Cerr is a sum over the N robots of each one's angular offset from the midpoint of its neighbours
(degrees), so a threshold T lets each robot be off by T / N on average, while uniform spacing is
360 / N: the share T / 360 of the spacing, whatever N. The default T = 0.1 N deg is 0.17 % of the
spacing for six robots but 28 % for a thousand, where a visibly uneven team already counts as
converged.
"""

from __future__ import annotations

LOOSE_SHARE = 0.05  # a threshold letting the mean offset exceed this share of the spacing means little


def loose_threshold(threshold_deg: float, robots: int) -> str | None:
    """One line saying why ``threshold_deg`` (on Cerr, degrees) is too loose to mean convergence for
    ``robots`` robots, or None when it is not (it allows a mean offset of at most ``LOOSE_SHARE`` of
    the uniform spacing: ``threshold_deg <= LOOSE_SHARE * 360``)."""
    share = threshold_deg / 360.0
    if share <= LOOSE_SHARE:
        return None
    return (f"the convergence threshold {threshold_deg:g} deg on Cerr (a sum over {robots} robots) lets each robot "
            f"be off by {threshold_deg / robots:.3g} deg on average, {100 * share:.0f} % of the uniform spacing "
            f"{360 / robots:.3g} deg, so 'converged' means little; set control.threshold_deg at most "
            f"{LOOSE_SHARE * 360:g} in the scenario")
