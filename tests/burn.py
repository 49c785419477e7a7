"""Run pytest with two CPU-burning processes of its own beside it, ended by pid however pytest ends.

    python -m tests.burn [PYTEST ARGUMENTS]

The test command runs the multi-process tests a second time this way (``make test``): they must hold
on a machine as busy as a shared CI runner, where every core is taken by someone else's work.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys

BURNERS = 2
BURN = "while True: pass"


def main(arguments: list[str]) -> int:
    burners = [subprocess.Popen([sys.executable, "-c", BURN]) for _ in range(BURNERS)]
    try:
        return subprocess.call([sys.executable, "-m", "pytest", *arguments])
    finally:
        for burner in burners:
            try:
                os.kill(burner.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            burner.wait()


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
