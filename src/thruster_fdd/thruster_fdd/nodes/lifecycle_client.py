"""Driving managed (lifecycle) nodes through their standard services, from any node.

``thruster-fdd up`` configures and activates the ESC drivers it starts, and deactivates them
(neutral) before it stops them; the tests walk a driver through every transition. The services
are the standard ``<node>/change_state`` and ``<node>/get_state`` (``lifecycle_msgs``), so any
lifecycle manager can do the same.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.node import Node
from rclpy.task import Future

from thruster_fdd.nodes.common import spin_until


def change_states(
    node: Node, executor: Any, targets: Sequence[str], transition: str, timeout_s: float
) -> dict[str, str]:
    """Request ``transition`` of every node in ``targets`` at once and wait for the answers.

    Parameters
    ----------
    node, executor : Node, executor
        The calling node and the executor that spins it (spun here while waiting).
    targets : sequence of str
        Fully qualified names of lifecycle nodes, e.g. ``/thruster/t0/esc_driver``.
    transition : str
        A transition label: ``configure``, ``activate``, ``deactivate``, ``cleanup``,
        ``shutdown``.
    timeout_s : float
        Longest wait in all (for the services to appear and for the answers), s.

    Returns
    -------
    dict of str to str
        For every target that did not make the transition, why (empty when all did).
    """
    deadline = time.monotonic() + timeout_s
    clients = {
        target: node.create_client(ChangeState, f"{target}/change_state") for target in targets
    }
    problems: dict[str, str] = {}
    try:
        spin_until(executor, lambda: all(c.service_is_ready() for c in clients.values()), deadline)
        futures = {}
        for target, client in clients.items():
            if not client.service_is_ready():
                problems[target] = f"no {target}/change_state service"
                continue
            request = ChangeState.Request()
            request.transition.label = transition
            futures[target] = client.call_async(request)
        spin_until(executor, lambda: all(f.done() for f in futures.values()), deadline)
        for target, future in futures.items():
            if not future.done():
                problems[target] = f"no answer to {transition} within {timeout_s:g} s"
            elif not future.result().success:
                problems[target] = f"{transition} failed (see the node's log)"
    finally:
        for client in clients.values():
            node.destroy_client(client)
    return problems


ASK_AGAIN_S = 2.0
"""Wait for an answer to ``get_state``'s question before it is asked again, s."""


def get_state(node: Node, executor: Any, target: str, timeout_s: float) -> str | None:
    """The current state label of lifecycle node ``target`` (``unconfigured``, ``inactive``,
    ``active``, ``finalized``), or None when it does not answer within ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    client = node.create_client(GetState, f"{target}/get_state")
    try:
        if not spin_until(executor, client.service_is_ready, deadline):
            return None
        # Asked again every ASK_AGAIN_S: the service may be ready to the client before the
        # server's answer can reach it, and Fast DDS then drops the answer ("failed to send
        # response (timeout)", ros2/rmw_fastrtps#706); the question changes nothing.
        futures: list[Future] = []
        while time.monotonic() < deadline:
            futures.append(client.call_async(GetState.Request()))
            wait = min(deadline, time.monotonic() + ASK_AGAIN_S)
            if spin_until(executor, lambda: any(f.done() for f in futures), wait):
                done = next(f for f in futures if f.done())
                return str(done.result().current_state.label)
        return None
    finally:
        node.destroy_client(client)
