"""The world's digests to the monitor in lockstep (world.process.Digests): what leaves when."""

from __future__ import annotations

from ringtrack.bus.keys import MONITOR, Keys
from ringtrack.bus.messages import SCHEMA, Command, Tick, decode, digest_entries, encode
from ringtrack.world.backlog import step_entries
from ringtrack.world.process import DIGEST_PERIOD_S, Digests

RUN = 0x2000ABCD
ROBOTS = 6


class Sent(list):
    """A participant's sends, as (destination, message)."""

    def __init__(self) -> None:
        super().__init__()
        self.keys, self.robots = Keys(RUN), ROBOTS

    def send(self, destination: str, message: object) -> int:
        self.append((destination, message))
        return 0


def tick(step: int) -> Tick:
    return Tick(SCHEMA, RUN, step, 0.1 * step, [(0.0, 0.0)] * ROBOTS, (1.0, 1.0), list(range(ROBOTS)))


def command(step: int, robot: int) -> tuple[Command, int]:
    return Command(SCHEMA, RUN, step, robot, (0.0, 0.0), 0, 0.0, (1, 1), (1.0, 1.0)), 64


def add_step(digests: Digests, step: int, commands: int = ROBOTS, now: float = 0.0) -> None:
    digests.add(step_entries(step, tick(step), [(robot, 70) for robot in range(ROBOTS)],
                             [command(step, robot % ROBOTS) for robot in range(commands)], ROBOTS), now)


def test_a_digest_leaves_full_and_the_rest_at_the_flush_in_step_order() -> None:
    sent = Sent()
    digests = Digests(sent)  # type: ignore[arg-type]
    for step in range(1, 26):
        add_step(digests, step)
    assert len(sent) == 2 and len(digests.pending) == 5  # ten entries each; five wait
    digests.flush()
    assert digest_entries(ROBOTS) == 10
    assert [destination for destination, _ in sent] == [MONITOR] * 3
    entries = [entry for _, digest in sent for entry in digest.entries]
    assert [len(digest.entries) for _, digest in sent] == [10, 10, 5]
    assert [entry.step for entry in entries] == list(range(1, 26))
    assert all(entry.tick == tick(entry.step) and len(entry.commands) == ROBOTS for entry in entries)
    route = Keys(RUN).parse(Keys(RUN).data(MONITOR, "world", "digest"))
    assert all(decode(encode(digest), route, RUN, ROBOTS) == digest for _, digest in sent)


def test_a_step_with_more_commands_than_robots_takes_entries_of_the_teams_size() -> None:
    sent = Sent()
    digests = Digests(sent)  # type: ignore[arg-type]
    add_step(digests, 1, commands=2 * ROBOTS + 1)  # forged or repeated commands besides the team's
    digests.flush()
    ((_, digest),) = sent
    assert [(entry.step, entry.tick is not None, len(entry.measurements), len(entry.commands))
            for entry in digest.entries] == [(1, True, ROBOTS, ROBOTS), (1, False, 0, ROBOTS), (1, False, 0, 1)]


def test_entries_wait_for_later_steps_at_most_the_digest_period() -> None:
    sent = Sent()
    digests = Digests(sent)  # type: ignore[arg-type]
    add_step(digests, 1, now=10.0)
    add_step(digests, 2, now=10.0 + DIGEST_PERIOD_S / 2)
    digests.send_due(10.0 + DIGEST_PERIOD_S * 0.99)
    assert sent == []  # the oldest has not waited its time
    digests.send_due(10.0 + DIGEST_PERIOD_S)
    add_step(digests, 3, now=20.0)  # the first of the next digest: it waits from its own end
    add_step(digests, 4, now=20.0 + DIGEST_PERIOD_S * 1.01)  # leaves with the one that waited too long
    assert [[entry.step for entry in digest.entries] for _, digest in sent] == [[1, 2], [3, 4]]
    assert digests.pending == [] and digests.due is None
