"""What the node tests share: a probe node of their own and the node processes under test
(stopped with ``thruster_fdd.lifetime.stop_children``, as ``up`` and ``replay`` stop theirs).

Each test graph runs the node under test as a process from its entry module (as ``thruster-fdd
up`` starts it) and talks to it from a probe node in the test process, on a private rclpy
context spun by a single-threaded executor in the test's thread.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from types import TracebackType


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
        """Spin until ``predicate()`` holds (True) or ``timeout_s`` s pass (False)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=step_s)
            if predicate():
                return True
        return False

    def spin(self, seconds: float) -> None:
        """Spin for ``seconds`` s."""
        self.spin_until(lambda: False, seconds)

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


def start_node(
    module: str, namespace: str | None = None, params: Mapping[str, object] | None = None
) -> subprocess.Popen[bytes]:
    """Start ``thruster_fdd.nodes.<module>`` with ``--ros-args`` for a namespace and parameters."""
    cmd = [sys.executable, "-m", f"thruster_fdd.nodes.{module}", "--ros-args"]
    if namespace is not None:
        cmd += ["-r", f"__ns:={namespace}"]
    for name, value in (params or {}).items():
        cmd += ["-p", f"{name}:={value}"]
    return subprocess.Popen(cmd)
