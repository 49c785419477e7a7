"""Test configuration: hypothesis defaults shared by every test file, and the ``processes`` marker
kept honest (shared helpers live in helpers.py).

Hypothesis profiles (``HYPOTHESIS_PROFILE``, see ``tests.helpers.EXAMPLE_SCALE``): ``dev`` by default
(30 % of each property test's examples, for the edit-test loop), ``ci`` (the full counts; ``make test``
and CI), ``thorough`` (ten times the full counts).

Markers (registered in pyproject.toml): ``processes`` (the test starts OS processes), ``realtime``
(it runs the realtime clock) and ``root`` (it needs root). A test without ``processes`` that starts
a process fails at once, naming the marker, so ``pytest -m "not processes"`` is the pure suite.

The suite runs on one pytest-xdist worker per core (``-n auto`` in pyproject.toml; ``-n 0`` for a
single process), so two tests may run at once, each on a machine the other loads: every test that
starts processes sizes its waits from what it measures, not from a quiet machine.
"""

from __future__ import annotations

import multiprocessing.util
import os
import platform
import signal
import subprocess
from pathlib import Path

import matplotlib
import pytest
from hypothesis import HealthCheck, settings

from tests.helpers import EXAMPLE_SCALE, PROFILE, examples

_COMMON = dict(
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
    print_blob=True,
)
DEFAULT_EXAMPLES = 50  # a property test without its own count draws this many under "ci"
for _profile in EXAMPLE_SCALE:
    settings.register_profile(_profile, max_examples=examples(DEFAULT_EXAMPLES, _profile), **_COMMON)
settings.load_profile(PROFILE)

# platform.platform() runs `uname -p` once and caches it; run it here, so that a benchmark describing
# the machine does not count as starting a process.
platform.platform()
# Tests press Ctrl-C on their children (SIGINT). A shell that starts the suite in the background
# without job control makes it ignore SIGINT, and an ignored signal is inherited across exec: the
# children would ignore it too. Restore Python's own handler (children then start with the default).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
# matplotlib builds its font cache once per machine, running `fc-list`: build it here on a fresh one.
if not list(Path(matplotlib.get_cachedir()).glob("fontlist-*.json")):
    import matplotlib.font_manager  # noqa: F401


@pytest.fixture(autouse=True)
def _processes_need_the_marker(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """Refuse every way of starting a process (subprocess and asyncio children, fork, multiprocessing)
    in a test not marked ``processes``."""
    if request.node.get_closest_marker("processes") is None:
        def refuse(*args: object, **kwargs: object) -> None:
            raise AssertionError(f"{request.node.nodeid} starts an OS process: mark it @pytest.mark.processes")

        monkeypatch.setattr(subprocess.Popen, "_execute_child", refuse)
        monkeypatch.setattr(os, "fork", refuse)
        monkeypatch.setattr(os, "posix_spawn", refuse)
        monkeypatch.setattr(multiprocessing.util, "spawnv_passfds", refuse)
