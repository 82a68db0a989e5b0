"""Driving managed (lifecycle) nodes through their standard services, from any node.

``thruster-fdd up`` configures and activates the ESC drivers it starts, and deactivates them
(neutral) before it stops them; the tests walk a driver through every transition. The services
are the standard ``<node>/change_state`` and ``<node>/get_state`` (``lifecycle_msgs``), so any
lifecycle manager can do the same.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.node import Node
from rclpy.task import Future

from thruster_fdd.nodes.common import spin_until

ASK_AGAIN_S = 2.0
"""Wait for an answer before a question is asked again (``ask``, ``get_state``) or the state is
asked (``change_states``), s."""


GOAL_STATE = {
    "configure": "inactive",
    "activate": "active",
    "deactivate": "inactive",
    "cleanup": "unconfigured",
    "shutdown": "finalized",
}
"""The primary state each transition leads to when it succeeds."""

FROM_STATES = {
    "configure": ("unconfigured",),
    "activate": ("inactive",),
    "deactivate": ("active",),
    "cleanup": ("inactive",),
    "shutdown": ("unconfigured", "inactive", "active"),
}
"""The primary states each transition starts from: a node still in one has not begun it."""


def change_states(
    node: Node,
    executor: Any,
    targets: Sequence[str],
    transition: str,
    timeout_s: float,
    abort: Callable[[], str | None] = lambda: None,
) -> dict[str, str]:
    """Request ``transition`` of every node in ``targets`` at once and wait for the answers.

    An answer can be lost on the way (Fast DDS drops the answer to a client whose response
    reader it has not matched yet, ros2/rmw_fastrtps#706). So a target that has not answered
    within ``ASK_AGAIN_S`` is asked its state: in the transition's goal state it made the
    transition; still in a state the transition starts from, it has not begun it and is asked
    again; in between (``configuring``, ...) it is waited for. A refusal after a repeated
    request counts only if the node is not in the goal state (the first request may have done
    it, its answer lost).

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
    abort : callable
        Checked at every step of every wait (``spin_until``'s, at least every 50 ms): a reason
        (a stop request, a dead process) ends the waiting at once, and every target not done
        yet gets that reason.

    Returns
    -------
    dict of str to str
        For every target that did not make the transition, why (empty when all did).

    Raises
    ------
    ValueError
        For a transition label not listed above (a bug in the caller).
    """
    if transition not in GOAL_STATE:
        raise ValueError(f"unknown lifecycle transition {transition!r}")
    deadline = time.monotonic() + timeout_s
    clients = {
        target: node.create_client(ChangeState, f"{target}/change_state") for target in targets
    }
    problems: dict[str, str] = {}

    def ask(target: str) -> Future:
        request = ChangeState.Request()
        request.transition.label = transition
        return clients[target].call_async(request)

    try:
        spin_until(
            executor,
            lambda: abort() is not None or all(c.service_is_ready() for c in clients.values()),
            deadline,
        )
        reason = abort()
        if reason is not None:
            return dict.fromkeys(targets, reason)
        asked: dict[str, list[Future]] = {}
        for target, client in clients.items():
            if client.service_is_ready():
                asked[target] = [ask(target)]
            else:
                problems[target] = f"no {target}/change_state service"
        while asked and time.monotonic() < deadline:
            wait = min(deadline, time.monotonic() + ASK_AGAIN_S)
            spin_until(
                executor,
                lambda: (
                    abort() is not None or all(any(f.done() for f in fs) for fs in asked.values())
                ),
                wait,
            )
            reason = abort()
            if reason is not None:
                return problems | dict.fromkeys(asked, reason)
            for target, futures in list(asked.items()):
                answers = [f.result().success for f in futures if f.done()]
                if any(answers):
                    del asked[target]
                    continue
                state = None
                if not answers or len(futures) > 1:
                    # A refusal of the only request is the answer; otherwise the state tells.
                    left = deadline - time.monotonic()
                    wait_s = min(ASK_AGAIN_S, max(left, 0.0))
                    state = get_state(node, executor, target, wait_s, abort)
                if state == GOAL_STATE[transition]:
                    del asked[target]
                elif answers:
                    problems[target] = f"{transition} failed (see the node's log)"
                    del asked[target]
                elif state in FROM_STATES[transition]:
                    futures.append(ask(target))
        for target in asked:
            problems[target] = f"no answer to {transition} within {timeout_s:g} s"
    finally:
        for client in clients.values():
            node.destroy_client(client)
    return problems


def get_state(
    node: Node,
    executor: Any,
    target: str,
    timeout_s: float,
    abort: Callable[[], str | None] = lambda: None,
) -> str | None:
    """The current state label of lifecycle node ``target`` (``unconfigured``, ``inactive``,
    ``active``, ``finalized``), or None when it does not answer within ``timeout_s`` or
    ``abort`` gives a reason first (as in :func:`change_states`)."""
    deadline = time.monotonic() + timeout_s
    client = node.create_client(GetState, f"{target}/get_state")
    try:
        ready = spin_until(
            executor, lambda: abort() is not None or client.service_is_ready(), deadline
        )
        if not ready or abort() is not None:
            return None
        answer = ask(executor, lambda: client.call_async(GetState.Request()), deadline, abort)
        return None if answer is None else str(answer.current_state.label)
    finally:
        node.destroy_client(client)


def ask(
    executor: Any,
    request: Callable[[], Future],
    deadline: float,
    abort: Callable[[], str | None] = lambda: None,
) -> Any | None:
    """The result of the first answered call of ``request()`` (which sends a service request
    and returns its future), or None when none is answered before ``deadline``
    (``time.monotonic()``) or ``abort`` gives a reason first.

    The request is sent again every ``ASK_AGAIN_S``: a service may be ready to its client
    before the server's answer can reach it, and Fast DDS then drops the answer ("failed to
    send response (timeout)", ros2/rmw_fastrtps#706). ``request`` must leave the same state
    when it is served twice (a get, or a set to the same value).
    """
    futures: list[Future] = []
    while time.monotonic() < deadline:
        futures.append(request())
        wait = min(deadline, time.monotonic() + ASK_AGAIN_S)
        spin_until(executor, lambda: abort() is not None or any(f.done() for f in futures), wait)
        if abort() is not None:
            return None
        done = next((f for f in futures if f.done()), None)
        if done is not None:
            return done.result()
    return None
