"""The console: results on stdout, progress, warnings and errors on stderr, tables never cut."""

from __future__ import annotations

import math

from rich.console import Console, RenderableType
from rich.measure import Measurement
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from ringtrack.world.scenario import Scenario
from ringtrack.world.threshold import loose_threshold

out = Console()
# soft_wrap: a one-line message stays one line whatever the terminal width (errors are grepped).
err = Console(stderr=True, soft_wrap=True)


UNBOUNDED_WIDTH = 10_000  # columns a table may take off a terminal (a pipe or a file has no width)
SUMMARISED_ABOVE = 20  # robots (or links) from which a table shows min/median/max and the busiest only
BUSIEST = 5  # rows of the busiest robots (or links) such a summary keeps


class UsageError(ValueError):
    """A command-line value is unusable; the message is one line naming the flag and the fix."""




def show(renderable: RenderableType, console: Console | None = None) -> None:
    """Print a table (or any renderable) on ``console`` (default stdout), never cut: on a terminal at
    its width; off one (a pipe, a file: no width of its own) at the width the table needs, wider
    than the console if need be. A column of prose that should wrap says so with ``max_width``."""
    console = console or out
    if console.is_terminal:
        console.print(renderable)
        return
    unbounded = console.options.update(width=UNBOUNDED_WIDTH, max_width=UNBOUNDED_WIDTH)
    needed = min(Measurement.get(console, unbounded, renderable).maximum, UNBOUNDED_WIDTH)
    width = console.width
    if needed <= width:
        console.print(renderable)
        return
    console.width = needed  # a console never prints wider than itself
    try:
        console.print(renderable)
    finally:
        console.width = width


def progress_bar(console: Console | None = None, disable: bool = False) -> Progress:
    """The progress display of a long command: on ``console`` (default stderr), one bar per task with
    its count done and the time elapsed; ``disable`` shows nothing at all."""
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=console or err, disable=disable)










def warn_if_threshold_loose(scenario: Scenario) -> None:
    """One warning line on stderr when the scenario's convergence threshold is too loose to mean
    anything for its team size (:func:`world.threshold.loose_threshold`)."""
    problem = loose_threshold(math.degrees(scenario.threshold), scenario.robots)
    if problem is not None:
        err.print(f"ringtrack: warning: {problem}", highlight=False, markup=False)
