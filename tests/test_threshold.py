"""A convergence threshold too loose for the team size is said in one line (Cerr sums over robots)."""

from __future__ import annotations

import subprocess

import pytest

from ringtrack.world.threshold import LOOSE_SHARE, loose_threshold
from tests.helpers import RINGTRACK


@pytest.mark.parametrize(("robots", "loose"), [(6, False), (64, False), (180, False), (181, True), (1000, True)])
def test_the_default_threshold_is_loose_beyond_180_robots(robots: int, loose: bool) -> None:
    # default 0.1 N deg: a mean offset of 0.1 deg per robot against a spacing of 360 / N deg
    assert (loose_threshold(0.1 * robots, robots) is not None) == loose
    assert (0.1 * robots / 360 > LOOSE_SHARE) == loose


@pytest.mark.processes
def test_simulate_a_thousand_robots_warns_in_one_line() -> None:
    result = subprocess.run([*RINGTRACK, "simulate", "--robots", "1000", "--steps", "2"], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0
    assert result.stderr.splitlines() == [
        "ringtrack: warning: the convergence threshold 100 deg on Cerr (a sum over 1000 robots) lets each robot be "
        "off by 0.1 deg on average, 28 % of the uniform spacing 0.36 deg, so 'converged' means little; set "
        "control.threshold_deg at most 18 in the scenario"]
    quiet = subprocess.run([*RINGTRACK, "simulate", "--steps", "2"], capture_output=True, text=True, timeout=120)
    assert quiet.stderr == ""
