"""The robot protocol state machine (agents/node.py), without any bus."""

from __future__ import annotations

import itertools

import msgspec
import numpy as np
import pytest

from ringtrack.agents import engine
from ringtrack.agents.laws import Trigger
from ringtrack.agents.node import RobotNode
from ringtrack.agents.team import run_team
from ringtrack.bus.messages import NONCE_BASE, SCHEMA, Command, End, Measurement, Reply, Request
from ringtrack.world.scenario import load_scenario
from ringtrack.world.state import WorldState

RUN = 0x51


def make_node(robot: int = 2, **overrides: object) -> tuple[RobotNode, WorldState]:
    scenario = load_scenario("paper-stationary", **overrides)
    counter = itertools.count(1000)
    return RobotNode(robot, scenario, RUN, nonce=lambda: next(counter)), WorldState(scenario, 0, RUN, 100)


def reply_to(request: Request, world: WorldState) -> Reply:
    position = tuple(float(v) for v in world.positions[request.receiver])
    return Reply(SCHEMA, RUN, request.step, request.receiver, request.sender, request.nonce, position)


def test_default_nonces_are_five_bytes_and_differ_between_robots() -> None:
    """Each robot draws its nonces from a generator of its own, seeded from the OS."""
    scenario = load_scenario("paper-stationary")
    drawn = [[node._nonce() for _ in range(200)] for node in (RobotNode(robot, scenario, RUN) for robot in (0, 0, 1))]
    assert all(NONCE_BASE <= nonce < NONCE_BASE + 2**31 for nonces in drawn for nonce in nonces)
    assert all(len(msgspec.msgpack.encode(nonce)) == 5 for nonce in drawn[0])
    assert len({nonce for nonces in drawn for nonce in nonces}) == 600


def test_a_poll_sends_two_requests_and_commands_after_both_replies() -> None:
    node, world = make_node()
    out = node.handle(world.measurement(2))
    assert [destination for destination, _ in out] == ["r1", "r3"]
    first, second = (message for _, message in out)
    assert isinstance(first, Request) and isinstance(second, Request)
    assert (first.step, first.sender, first.receiver) == (1, 2, 1)
    assert (second.step, second.sender, second.receiver) == (1, 2, 3)
    assert first.nonce != second.nonce
    assert node.trigger == Trigger.START and node.polls == 1
    assert node.handle(reply_to(first, world)) == []
    (destination, command), = node.handle(reply_to(second, world))
    assert destination == "world" and isinstance(command, Command)
    assert (command.step, command.robot, command.trigger) == (1, 2, int(Trigger.START))


def test_replies_in_either_order_give_the_same_command() -> None:
    commands = []
    for order in ((0, 1), (1, 0)):
        node, world = make_node()
        requests = [message for _, message in node.handle(world.measurement(2))]
        for index in order:
            out = node.handle(reply_to(requests[index], world))
        commands.append(out[0][1])
    assert commands[0] == commands[1]


def test_stale_forged_or_unasked_replies_are_ignored() -> None:
    node, world = make_node()
    request, _ = (message for _, message in node.handle(world.measurement(2)))
    forged = Reply(SCHEMA, RUN, 1, 1, 2, request.nonce + 1, (0.0, 0.0))
    unasked = Reply(SCHEMA, RUN, 1, 4, 2, request.nonce, (0.0, 0.0))
    assert node.handle(forged) == [] and node.handle(unasked) == []
    assert node.ignored_replies == 2
    assert node.handle(reply_to(request, world)) == []  # the genuine one still counts
    assert node.awaiting and 1 not in node.awaiting


def test_a_request_from_the_future_waits_for_our_measurement() -> None:
    node, world = make_node()
    early = Request(SCHEMA, RUN, 1, 1, 2, 77)
    assert node.handle(early) == []
    out = node.handle(world.measurement(2))
    reply = out[0][1]
    assert isinstance(reply, Reply) and out[0][0] == "r1"
    assert reply.nonce == 77 and reply.step == 1
    assert reply.position == tuple(float(v) for v in world.positions[2])


def test_a_lost_answer_settles_the_poll_and_leaves_that_side_stale() -> None:
    node, world = make_node(strategy="constant")  # polls every step
    for step in (1, 2, 3):
        out = node.handle(world.measurement(2))
        if step < 3:  # both sides answer at steps 1 and 2
            *_, (_, command) = [node.handle(reply_to(message, world)) for _, message in out][-1] or [None]
            world.accept(command)
            world.advance()
    assert node.trigger and len(node.awaiting) == 2
    ages_before = (int(node.controller.predecessor_age), int(node.controller.successor_age))
    assert node.on_lost(3) == []  # the successor's answer will not come: still waiting for the other
    assert node.on_lost(3) == []  # a second notice for the same side changes nothing
    request = next(message for _, message in out if isinstance(message, Request) and message.receiver == 1)
    (destination, command), = node.handle(reply_to(request, world))
    assert destination == "world" and isinstance(command, Command)  # settled within the step
    assert int(node.controller.predecessor_age) == 0  # fresh
    assert int(node.controller.successor_age) == ages_before[1]  # stale, and it goes on ageing


def test_a_lost_late_copy_of_an_earlier_answer_does_not_cancel_the_open_poll() -> None:
    node, world = make_node(strategy="constant")
    (_, first), (_, second) = node.handle(world.measurement(2))
    node.handle(reply_to(first, world))
    (_, command), = node.handle(reply_to(second, world))
    world.accept(command)
    world.advance()
    node.handle(world.measurement(2))  # step 2: a new poll, new nonces
    assert set(node.awaiting) == {1, 3}
    assert node.on_lost(1, first.nonce) == []  # a dropped late copy of step 1's answer from robot 1
    assert set(node.awaiting) == {1, 3}  # still waiting for robot 1's answer of step 2


def test_a_robot_joining_a_running_team_keeps_a_request_for_its_first_step() -> None:
    node, world = make_node()
    for _ in range(499):  # the team is at step 500 when this robot (re)starts
        world.advance()
    early = Request(SCHEMA, RUN, 500, 1, 2, 77)  # its neighbour's poll overtakes its first measurement
    assert node.handle(early) == []
    out = node.handle(world.measurement(2))
    replies = [message for _, message in out if isinstance(message, Reply)]
    assert [(reply.step, reply.nonce) for reply in replies] == [(500, 77)]


def test_a_flood_of_far_future_requests_cannot_grow_the_robots_memory() -> None:
    from ringtrack.agents.node import BUFFERED_LIMIT, KEPT_STEPS

    node, world = make_node()
    node.handle(world.measurement(2))  # at step 1: it knows the step now
    far = [Request(SCHEMA, RUN, KEPT_STEPS + 2 + k, 1, 2, k) for k in range(1000)]
    near = [Request(SCHEMA, RUN, 2 + k % KEPT_STEPS, 3, 2, k) for k in range(1000)]
    for request in far + near:
        assert node.handle(request) == []
    assert len(node.buffered) == BUFFERED_LIMIT
    assert node.ignored_requests == len(far) + len(near) - BUFFERED_LIMIT
    world.advance()
    out = node.handle(world.measurement(2))  # step 2: the buffered requests for step 2 are answered
    assert [message.step for _, message in out if isinstance(message, Reply)] == [2] * (BUFFERED_LIMIT // KEPT_STEPS)


def test_a_reply_describes_the_start_of_the_requested_step() -> None:
    node, world = make_node()
    requests = [message for _, message in node.handle(world.measurement(2))]
    for request in requests:
        node.handle(reply_to(request, world))
    start = tuple(float(v) for v in world.positions[2])
    moved = (start[0] + 0.01, start[1])  # the robot has moved on by step 2
    node.handle(Measurement(SCHEMA, RUN, 2, 0.1, 2, moved, 1.0))
    late = node.handle(Request(SCHEMA, RUN, 1, 3, 2, 9))
    assert late[0][1].step == 1 and late[0][1].position == start


def test_without_a_poll_only_a_command_is_sent_and_duplicates_are_dropped() -> None:
    node, world = make_node(strategy="self")
    requests = [message for _, message in node.handle(world.measurement(2))]
    for request in requests:
        node.handle(reply_to(request, world))
    quiet = 0
    for step in range(2, 40):
        measurement = Measurement(SCHEMA, RUN, step, 0.0, 2, tuple(float(v) for v in world.positions[2]), 1.0)
        out = node.handle(measurement)
        if node.trigger == 0:
            quiet += 1
            assert len(out) == 1 and out[0][0] == "world"
        else:
            for _, request in out:
                node.handle(reply_to(request, world))
        assert node.handle(measurement) == []  # a duplicate is ignored
    assert quiet > 0


def test_end_finishes_the_node() -> None:
    node, _ = make_node()
    node.handle(End(SCHEMA, RUN, 10, "done", 1.0))
    assert node.finished


def test_unknown_robot_id_is_refused() -> None:
    scenario = load_scenario("paper-stationary")
    with pytest.raises(ValueError, match="--id 6: the team has robots 0..5"):
        RobotNode(6, scenario, RUN)


@pytest.mark.parametrize("strategy", ["self", "constant"])
def test_a_team_of_nodes_equals_the_engine(strategy: str) -> None:
    """Six nodes exchanging messages in one process (any delivery order) equal the engine."""
    scenario = load_scenario("paper-stationary", strategy=strategy)
    rng = np.random.default_rng(3)
    steps = 200
    team = run_team(scenario, steps, RUN, pick=lambda queued: int(rng.integers(queued)))
    twin = engine.run(scenario, steps=steps)
    assert np.array_equal(team.triggers, twin.triggers[:, 0])
    assert np.max(np.abs(np.unwrap(team.angles, axis=0) - twin.angles[:, 0])) < 1e-9
    polls = int(np.count_nonzero(team.triggers))
    assert team.messages == 2 * 6 * steps + 4 * polls  # a measurement and a command each, 4 per poll
