"""A probe: a node on a private rclpy context, spun in the caller's thread, that talks to a
node graph from outside it (``thruster-fdd replay`` and the node tests use it).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from types import TracebackType
from typing import Any


class Probe:
    """A node named ``name`` on its own rclpy context, with a single-threaded executor.

    A context manager: leaving it shuts the executor down before destroying the node (the
    order ``nodes/common.run`` keeps), then the context.
    """

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.context = Context()
        rclpy.init(context=self.context)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(
        self, predicate: Callable[[], bool], timeout_s: float, step_s: float = 0.01
    ) -> bool:
        """Spin until ``predicate()`` holds (True) or ``timeout_s`` s pass (False); it is checked
        before each spin of at most ``step_s`` s."""
        deadline = time.monotonic() + timeout_s
        while not predicate():
            if time.monotonic() >= deadline:
                return False
            self.executor.spin_once(timeout_sec=step_s)
        return True

    def spin(self, seconds: float) -> None:
        """Spin for ``seconds`` s."""
        self.spin_until(lambda: False, seconds)

    def ask(self, request: Callable[[], Any], timeout_s: float) -> Any | None:
        """``lifecycle_client.ask`` on this probe's executor: the result of the first answered
        call of ``request()``, sent again while no answer comes, or None after ``timeout_s``."""
        from thruster_fdd_shore.nodes.lifecycle_client import ask

        return ask(self.executor, request, time.monotonic() + timeout_s)

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> Probe:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()
