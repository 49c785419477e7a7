"""The live dashboard: what a team is doing and what every message cost.

:class:`TeamModel` is built from run-log step and event records, fed live by the monitor as it
writes them or read back from a log by ``ringtrack replay`` in file order, so both show exactly the
same thing. :class:`Dashboard` renders a model with rich: the region drawn in the terminal with the
robots, the true target and the estimates; a row per robot, with the state of its links to its ring
neighbours; traffic totals and rates, the messages saved against the constant strategy; Cerr and
Terr sparklines. It adapts to the console size at every render.
"""

from __future__ import annotations

import math
import time

import numpy as np
from rich import box
from rich.console import Console, ConsoleOptions, Group, RenderableType, RenderResult
from rich.table import Table
from rich.text import Text

from ringtrack.agents.laws import reason_text
from ringtrack.tools.monitor.state import CATEGORIES, HISTORY, LINK_MEMORY_STEPS, TeamModel

SPARKS = "▁▂▃▄▅▆▇█"

REASON_WIDTH = 19  # characters of the last-trigger column at most ("T1+T2+T3+unk @12345" fits)

LINK_STYLES = {"ok": "green", "dup": "yellow", "delay": "yellow"}  # any other state (a loss) is red


def robot_label(robot: int) -> str:
    """One character per robot on the map: 0-9, then a-z, then A-Z, then '*'."""
    digits = "0123456789abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
    return digits[robot] if robot < len(digits) else "*"


# ---------------------------------------------------------------------------- rendering
def energy_text(energy_j: dict[str, list[float]]) -> Text:
    """The team's radio energy (known once the robots have reported it, at the end of a run)."""
    per_robot = [transmit + receive for transmit, receive in energy_j.values()]
    return Text.assemble(("radio energy: ", "bold"), f"team {1e3 * sum(per_robot):.2f} mJ, per robot "
                         f"{1e3 * min(per_robot):.2f}-{1e3 * max(per_robot):.2f} mJ")


CELL_ASPECT = 2.0  # a terminal cell is about twice as tall as it is wide
MIN_MAP = 10  # map columns at least (narrower consoles drop robot columns first, then use the compact list)
SIDE_WIDTH = 56  # columns the traffic table and the figures beside it need


def sparkline(values: list[float], width: int) -> Text:
    """``values`` (most recent last) as block characters, scaled between their min and max."""
    values = [value for value in values if not math.isnan(value)][-width:]
    if not values:
        return Text("-")
    low, high = min(values), max(values)
    span = high - low or 1.0
    return Text("".join(SPARKS[min(len(SPARKS) - 1, int((value - low) / span * len(SPARKS)))] for value in values))


def map_size(vertices: np.ndarray, max_width: int, max_height: int) -> tuple[int, int]:
    """The largest (columns, rows) within the bounds that keep the region's aspect ratio on terminal
    cells twice as tall as wide (a tall region gets a narrow map, never a squashed one)."""
    aspect = float(np.ptp(vertices[:, 1]) / max(np.ptp(vertices[:, 0]), 1e-9))  # height / width, metres
    rows = max(3, max_height)
    columns = round(CELL_ASPECT * rows / aspect)
    if columns > max_width:
        columns = max_width
        rows = max(3, min(max_height, round(columns * aspect / CELL_ASPECT)))
    return max(3, columns), rows


def region_map(model: TeamModel, width: int, height: int) -> Text:
    """The region's boundary, the robots (their labels), the true target (x) and estimates (+)."""
    vertices = model.scenario.region.vertices
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    span = np.maximum(high - low, 1e-9)

    def cell(point: np.ndarray) -> tuple[int, int]:
        column = int(round((point[0] - low[0]) / span[0] * (width - 1)))
        row = int(round((high[1] - point[1]) / span[1] * (height - 1)))
        return min(max(row, 0), height - 1), min(max(column, 0), width - 1)

    grid = [[(" ", "")] * width for _ in range(height)]
    for start, end in zip(vertices, np.roll(vertices, -1, axis=0), strict=True):
        for fraction in np.linspace(0.0, 1.0, 4 * (width + height)):
            row, column = cell(start + fraction * (end - start))
            grid[row][column] = ("·", "grey50")
    if model.centres is not None:
        for centre in model.centres:
            if centre is not None:
                row, column = cell(np.asarray(centre))
                grid[row][column] = ("+", "yellow")
    if model.target is not None:
        row, column = cell(model.target)
        grid[row][column] = ("x", "bold red")
    if model.positions is not None:
        for index, (position, status) in enumerate(zip(model.positions, model.robots, strict=True)):
            row, column = cell(position)
            style = "dim red" if not status.alive else "bold magenta" if status.polled_now else "bold cyan"
            grid[row][column] = (robot_label(index), style)
    text = Text(no_wrap=True, overflow="crop")
    for line in grid:
        for character, style in line:
            text.append(character, style)
        text.append("\n")
    text.rstrip()
    return text


# Robot columns, widest set first: the dashboard takes the first whose table fits beside the map.
ROBOT_COLUMNS = (
    ("robot", "links", "angle", "gV", "ubd", "ages", "polls", "sent", "recv", "last trigger"),
    ("robot", "links", "angle", "ubd", "polls", "sent", "recv", "last trigger"),
    ("robot", "links", "angle", "ubd", "polls", "last trigger"),
    ("robot", "links", "angle", "polls"),
)
MEASURING = Console(width=10_000)  # measures tables unclamped: a console clamps to its own width

# The legend line, most needed first: (what it explains, short text, long text); an entry whose
# column is not shown is left out.
LEGEND = (
    ("last trigger", "T1 ubd, T2/T3 succ/pred order", "triggers: T1 ubd too large, T2 order with successor, "
                     "T3 with predecessor, unk unknown neighbour, every: constant strategy"),
    ("ubd", "ubd uncertainty bound", "ubd bound on the neighbours' motion since heard"),
    ("gV", "gV guaranteed midpoint", "gV guaranteed midpoint of the neighbours"),
    ("ages", "ages: since heard", "ages: steps since pred,succ were heard"),
    ("map", "x target + estimate", "map: 0-9a-z robots (magenta: polled this step), x target, + estimates"),
    ("links", "links pred|succ", f"links pred|succ: ok or the last fault of {LINK_MEMORY_STEPS} steps"),
    ("sent", "msgs/B", "sent/recv: robot-to-robot msgs/bytes"),
)


def robot_cells(model: TeamModel, index: int) -> dict[str, str | Text]:
    """Every robot column's cell for robot ``index``."""
    status = model.robots[index]
    return {
        "robot": f"r{index} {robot_label(index)}",
        "links": links_text(model, index),
        "angle": _degrees(status.angle),
        "gV": _degrees(status.midpoint),
        "ubd": _degrees(status.ubd, 3),
        "ages": f"{status.ages[0]},{status.ages[1]}" if status.ages else "-",
        "polls": str(status.polls),
        "sent": f"{status.sent[0]}/{model.size_text(status.sent[1])}",
        "recv": f"{status.received[0]}/{model.size_text(status.received[1])}",
        "last trigger": f"{reason_text(status.last_reason)} @{status.last_reason_step}" if status.last_reason else "-",
    }


def robots_table(rows: list[dict[str, str | Text]], columns: tuple[str, ...]) -> Table:
    """One line per robot of ``rows`` (cells of :func:`robot_cells`) with ``columns``."""
    table = Table(box=box.SIMPLE_HEAD, padding=(0, 1), collapse_padding=True, pad_edge=False, expand=False,
                  show_edge=False)
    for column in columns:
        table.add_column(column, justify="right", no_wrap=True)
    for cells in rows:
        table.add_row(*(cells[column] for column in columns))
    return table


def compact_line(cells: dict[str, str | Text], width: int) -> Text:
    """A robot in one line of at most ``width`` columns: label, links, angle, polls, last trigger."""
    line = Text.assemble(f"{cells['robot']} ", cells["links"], f" {cells['angle']} p{cells['polls']} "
                         f"{cells['last trigger']}", no_wrap=True, overflow="ellipsis")
    line.truncate(width, overflow="ellipsis")
    return line


def links_text(model: TeamModel, robot: int) -> Text:
    """``predecessor|successor`` link states of a live robot, coloured; "down" for a dead one."""
    if not model.robots[robot].alive:
        return Text("down", "bold red")
    count = len(model.robots)
    states = [model.link_state(robot, (robot + side) % count) for side in (-1, 1)]
    return Text("|").join(Text(state, LINK_STYLES.get(state, "bold red")) for state in states)


def traffic_table(model: TeamModel) -> Table:
    table = Table(box=box.SIMPLE_HEAD, padding=(0, 1), show_edge=False, pad_edge=False)
    for column in ("traffic", "messages", "bytes", "msg per sim s"):
        table.add_column(column, justify="right", no_wrap=True)
    seconds = max(model.time + model.scenario.control.dt, 1e-9)
    for category in CATEGORIES:
        messages, size = model.totals[category]
        if category == "estimation" and messages == 0:
            continue
        label = "robot-to-robot" if category == "robot" else category
        table.add_row(label, str(messages), model.size_text(size), f"{messages / seconds:.1f}")
    return table


def _degrees(value: float, digits: int = 1) -> str:
    return "-" if math.isnan(value) else f"{value:.{digits}f}°"


def fit_line(pieces: list[tuple[str, str, int]], width: int, separator: str = " · ") -> Text:
    """One line of at most ``width`` columns from ``(text, style, priority)`` pieces: the pieces of the
    highest priority number are left out first until the rest fits (0: always kept), then it is cut."""
    kept = list(pieces)
    while len(separator.join(text for text, _, _ in kept)) > width and any(level for _, _, level in kept):
        worst = max(level for _, _, level in kept)
        index = max(i for i, (_, _, level) in enumerate(kept) if level == worst)
        del kept[index]
    line = Text(no_wrap=True, overflow="ellipsis")
    for index, (text, style, _) in enumerate(kept):
        if index:
            line.append(separator, "grey50")
        line.append(text, style)
    line.truncate(width, overflow="ellipsis")
    return line


def header_line(model: TeamModel, width: int) -> Text:
    """The top line: run, strategy, step and pace; pieces are left out on narrow consoles, never wrapped."""
    scenario = model.scenario
    rate = model.steps_per_second() if model.live else 0.0
    pace = f"replay x{model.replay_speed:g}" if model.replay_speed else f"{rate:.0f} steps/s" if rate else ""
    pieces = [
        ("ringtrack", "bold", 6),
        (scenario.name, "bold", 0),
        (f"{len(model.robots)} robots", "", 1),
        (f"{scenario.strategy.name} strategy", "", 2),
        (f"{scenario.estimation.mode} target", "", 4),
        (model.clock, "", 5),
        (f"step {model.step}/{model.steps}", "bold", 0),
        (f"t = {model.time:.1f} s", "", 3),
        *([(pace, "", 5)] if pace else []),
        ("starting" if model.step == 0 and model.status == "running" else model.status, "bold", 0),
    ]
    return fit_line(pieces, width)


def legend_line(shown: set[str], width: int) -> Text:
    """The bottom line explaining the map's symbols and the robot columns in ``shown``, in at most
    ``width`` columns: short wording, the long one for as many entries as fit, and the least needed
    entries left out when even the short ones do not fit."""
    entries = [entry for entry in LEGEND if entry[0] in shown]
    wording = [entry[1] for entry in entries]
    for index, entry in enumerate(entries):
        longer = [*wording[:index], entry[2], *wording[index + 1:]]
        if len(" · ".join(longer)) <= width:
            wording = longer
    return fit_line([(text, "grey50", index) for index, text in enumerate(wording)], width)


def startup_lines(model: TeamModel, width: int) -> list[Text]:
    """Before the first step: which participants are up, which are awaited, and what the start-up is doing."""
    waiting = [name for name in model.expected if name not in model.up]
    up = [name for name in model.expected if name in model.up]
    elapsed = time.monotonic() - model.started
    lines = [Text.assemble(("starting", "bold"), f": {len(up)}/{len(model.expected)} participants up "
                           f"after {elapsed:.1f} s" if model.expected else f" for {elapsed:.1f} s")]
    if up:
        lines.append(fit_line([("up: " + " ".join(up), "green", 0)], width))
    if waiting:
        lines.append(fit_line([("waiting for: " + " ".join(waiting), "yellow", 0)], width))
    if model.note:
        lines.append(fit_line([(model.note, "", 0)], width))
    return lines


class Dashboard:
    """A rich renderable of a :class:`TeamModel`, laid out for the console it is drawn on: a header line,
    the map (the region's true proportions) beside the traffic figures and one line per robot (as many
    as the height holds; the widest set of columns that fits, else a compact list), and a legend line."""

    def __init__(self, model: TeamModel) -> None:
        self.model = model

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        model = self.model
        width = options.max_width
        height = options.height or options.size.height
        body = max(3, height - 2)  # the header and the legend take a line each
        yield header_line(model, width)
        if model.step == 0:
            lines = startup_lines(model, width)
            map_columns, map_rows = map_size(model.scenario.region.vertices, width, body - len(lines))
            yield from lines
            yield region_map(model, map_columns, map_rows)
            yield legend_line({"map"}, width)
            return
        rows = [robot_cells(model, index) for index in range(len(model.robots))]
        vertices = model.scenario.region.vertices
        side_height = len(console.render_lines(Group(*self.side(width // 2)), options.update(width=width // 2,
                                                                                            height=None), pad=False))
        # Side by side: the map left of the figures and of the robot list ...
        columns, table_width = self.columns(rows, width - MIN_MAP - 2)
        map_limit = max(MIN_MAP, min(width // 2, width - 2 - max(table_width, SIDE_WIDTH)))
        map_columns, map_rows = map_size(vertices, map_limit, body)
        # ... or stacked, when the whole list fits below a larger map: the list then takes the full width.
        below = len(rows) + 2
        stacked_columns, _ = self.columns(rows, width)
        if stacked_columns and body - below >= side_height:
            stacked = map_size(vertices, min(width // 2, width - 2 - SIDE_WIDTH), body - below)
            if stacked[0] * stacked[1] > map_columns * map_rows:
                right = width - stacked[0] - 2
                top = Table.grid(padding=(0, 2))
                top.add_column(no_wrap=True, width=stacked[0])
                top.add_column(width=right)
                top.add_row(region_map(model, *stacked), Group(*self.side(right)))
                yield top
                yield robots_table(rows, stacked_columns)
                yield legend_line({"map", *stacked_columns}, width)
                return
        right = width - map_columns - 2
        room = body - side_height - (2 if columns else 0)  # the table's head and rule
        shown = rows if len(rows) <= room else rows[: max(0, room - 1)]
        robots: list[RenderableType] = [compact_line(cells, right) for cells in shown] if not columns else \
            [robots_table(shown, columns)] if shown else []
        if len(shown) < len(rows):
            robots.append(Text(f"… and {len(rows) - len(shown)} more robots (r{len(shown)}-r{len(rows) - 1})",
                               "grey50", no_wrap=True))
        layout = Table.grid(padding=(0, 2))
        layout.add_column(no_wrap=True, width=map_columns)
        layout.add_column(width=right)
        layout.add_row(region_map(model, map_columns, map_rows), Group(*self.side(right), *robots))
        yield layout
        yield legend_line({"map", *(columns or ("links", "last trigger"))}, width)

    def columns(self, rows: list[dict[str, str | Text]], width: int) -> tuple[tuple[str, ...], int]:
        """The widest :data:`ROBOT_COLUMNS` set whose table fits ``width`` columns, and its width;
        ``((), 0)`` when none does (the compact list)."""
        for columns in ROBOT_COLUMNS:
            table_width = MEASURING.measure(robots_table(rows, columns)).maximum
            if table_width <= width:
                return columns, table_width
        return (), 0

    def side(self, width: int) -> list[RenderableType]:
        """Traffic totals, Com-bar and messages saved, Cerr and Terr sparklines (each one line)."""
        model = self.model
        saved, share = model.saved()
        spark = max(8, min(HISTORY, width // 3))
        lines: list[RenderableType] = [traffic_table(model)]
        lines.append(fit_line([
            (f"Com-bar {model.com_bar_so_far():.3f} so far (constant 1)", "bold", 0),
            (f"saved {saved} msgs ({share:.0%}) vs constant", "", 1),
            (f"polls {model.polls}", "", 2),
        ], width))
        lines.append(Text.assemble(("Cerr ", "bold"), sparkline(list(model.cerr), spark),
                                   f" {model.cerr[-1]:.2f}°" if model.cerr else "", no_wrap=True))
        if model.scenario.estimation.mode != "known" and model.terr:
            lines.append(Text.assemble(("Terr ", "bold"), sparkline(list(model.terr), spark),
                                       f" {model.terr[-1]:.3f} m", no_wrap=True))
        if model.energy_j:
            lines.append(energy_text(model.energy_j))
        return lines
