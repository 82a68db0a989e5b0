"""The lifecycle client (``thruster_fdd.nodes.lifecycle_client``) against a real rclpy service
whose first answer is lost."""

from __future__ import annotations

import threading

import pytest
from probe import Probe

from thruster_fdd.nodes.lifecycle_client import get_state

pytestmark = pytest.mark.ros


def test_get_state_asks_again_when_an_answer_is_lost() -> None:
    """A lifecycle node's first answer may never reach a client that has just found it (Fast DDS
    drops it: "failed to send response (timeout)"); ``get_state`` asks again and takes the
    answer that comes. The server here holds its first answer until the test ends."""
    import rclpy
    from lifecycle_msgs.srv import GetState
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node

    context = Context()
    rclpy.init(context=context)
    server = Node("silent_once", context=context)
    release = threading.Event()
    calls: list[object] = []

    def answer(request: GetState.Request, response: GetState.Response) -> GetState.Response:
        calls.append(request)
        if len(calls) == 1:
            release.wait(30.0)
        response.current_state.label = "inactive"
        return response

    server.create_service(
        GetState, "/silent_once/get_state", answer, callback_group=ReentrantCallbackGroup()
    )
    executor = MultiThreadedExecutor(num_threads=2, context=context)
    executor.add_node(server)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        with Probe("asker") as probe:
            assert get_state(probe.node, probe.executor, "/silent_once", 15.0) == "inactive"
            release.set()
            probe.spin(0.5)
        assert len(calls) >= 2
    finally:
        release.set()
        executor.shutdown()
        server.destroy_node()
        rclpy.try_shutdown(context=context)
        thread.join(5.0)
