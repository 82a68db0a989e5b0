"""The lifecycle client (``thruster_fdd_shore.nodes.lifecycle_client``) against real rclpy services
whose first answer is lost."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest
from probe import Probe

from thruster_fdd_shore.nodes.lifecycle_client import change_states, get_state

pytestmark = pytest.mark.ros


@dataclass
class Server:
    """A lifecycle node's two services on their own context, spun by a multi-threaded executor
    in a thread. The first call of each service is held until ``release`` is set or 30 s pass
    (its answer never comes in time); ``do_first_transition`` says whether the held
    ``change_state`` call makes the transition before it waits (an answer lost) or not (a
    request lost)."""

    state: str = "unconfigured"
    do_first_transition: bool = True
    release: threading.Event = field(default_factory=threading.Event)
    get_calls: int = 0
    change_calls: list[str] = field(default_factory=list)


FROM = {"configure": "unconfigured", "activate": "inactive"}
GOAL = {"configure": "inactive", "activate": "active"}


@pytest.fixture
def server() -> Iterator[Server]:
    import rclpy
    from lifecycle_msgs.srv import ChangeState, GetState
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node

    s = Server()
    context = Context()
    rclpy.init(context=context)
    node = Node("silent_once", context=context)

    def get(request: GetState.Request, response: GetState.Response) -> GetState.Response:
        s.get_calls += 1
        if s.get_calls == 1:
            s.release.wait(30.0)
        response.current_state.label = s.state
        return response

    def change(
        request: ChangeState.Request, response: ChangeState.Response
    ) -> ChangeState.Response:
        label = request.transition.label
        s.change_calls.append(label)
        first = len(s.change_calls) == 1
        if first and not s.do_first_transition:
            s.release.wait(30.0)
            response.success = False
            return response
        ok = label in GOAL and s.state == FROM[label]
        if ok:
            s.state = GOAL[label]
        if first:
            s.release.wait(30.0)
        response.success = ok
        return response

    group = ReentrantCallbackGroup()
    node.create_service(GetState, "/silent_once/get_state", get, callback_group=group)
    node.create_service(ChangeState, "/silent_once/change_state", change, callback_group=group)
    executor = MultiThreadedExecutor(num_threads=3, context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield s
    finally:
        s.release.set()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        thread.join(5.0)


def test_get_state_asks_again_when_an_answer_is_lost(server: Server) -> None:
    """A lifecycle node's first answer may never reach a client that has just found it (Fast DDS
    drops it: "failed to send response (timeout)"); ``get_state`` asks again and takes the
    answer that comes."""
    server.state = "inactive"
    with Probe("asker") as probe:
        assert get_state(probe.node, probe.executor, "/silent_once", 15.0) == "inactive"
        server.release.set()
        probe.spin(0.5)
    assert server.get_calls >= 2


def test_the_probe_asks_again_when_an_answer_is_lost(server: Server) -> None:
    """``Probe.ask`` (what ``thruster-fdd reload`` asks the nodes' parameter services with) takes
    the answer to a repeated request when the first one's never comes, and gives None when no
    answer comes in time."""
    from lifecycle_msgs.srv import GetState

    server.state = "active"
    with Probe("asker") as probe:
        client = probe.node.create_client(GetState, "/silent_once/get_state")
        assert client.wait_for_service(timeout_sec=15.0)
        answer = probe.ask(lambda: client.call_async(GetState.Request()), 15.0)
        assert answer is not None
        assert answer.current_state.label == "active"
        assert server.get_calls >= 2
        server.get_calls = 0  # the next call is held again
        assert probe.ask(lambda: client.call_async(GetState.Request()), 1.0) is None
        server.release.set()
        probe.spin(0.5)


def test_a_transition_whose_answer_is_lost_is_read_from_the_state(server: Server) -> None:
    """The node made the transition but its answer does not come: the state tells, and the
    transition is not asked twice."""
    with Probe("asker") as probe:
        assert change_states(probe.node, probe.executor, ["/silent_once"], "configure", 15.0) == {}
        assert server.state == "inactive"
        assert server.change_calls == ["configure"]
        server.release.set()
        probe.spin(0.5)


def test_a_transition_not_begun_is_asked_again(server: Server) -> None:
    """The request did not lead to the transition (the node is still unconfigured, the answer
    does not come): it is asked again, and the second answer counts."""
    server.do_first_transition = False
    with Probe("asker") as probe:
        assert change_states(probe.node, probe.executor, ["/silent_once"], "configure", 15.0) == {}
        assert server.state == "inactive"
        assert server.change_calls[:2] == ["configure", "configure"]
        server.release.set()
        probe.spin(0.5)


def test_a_refused_transition_is_reported(server: Server) -> None:
    """A refusal that comes is the answer: activating an unconfigured node fails, whatever the
    state says."""
    server.release.set()
    with Probe("asker") as probe:
        problems = change_states(probe.node, probe.executor, ["/silent_once"], "activate", 15.0)
    assert problems == {"/silent_once": "activate failed (see the node's log)"}
    assert server.change_calls == ["activate"]
