"""Child processes of ``up`` and ``replay``: how a node's command line is built, and how
children stop when the process that started them dies.

``thruster-fdd up`` and ``replay`` start nodes as child processes. When such a parent is killed
outright (``kill -9``, a test's time-out), its children would run on as orphans and keep
publishing into the graph. A parent sets ``PARENT_PID_ENV`` in a child's environment; the child
calls :func:`stop_with_parent` at start and gets SIGINT, its normal clean stop, when the parent
dies. Linux only (``prctl``); elsewhere it does nothing.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping

PARENT_PID_ENV = "THRUSTER_FDD_PARENT_PID"
_PR_SET_PDEATHSIG = 1


def node_command(
    module: str, namespace: str | None = None, params: Mapping[str, object] | None = None
) -> list[str]:
    """The command line of node ``thruster_fdd.nodes.<module>`` in ``namespace`` with ROS
    parameter overrides ``params`` (``-p name:=value``)."""
    cmd = [sys.executable, "-m", f"thruster_fdd.nodes.{module}", "--ros-args"]
    if namespace is not None:
        cmd += ["-r", f"__ns:={namespace}"]
    for key, value in (params or {}).items():
        cmd += ["-p", f"{key}:={value}"]
    return cmd


def child_env() -> dict[str, str]:
    """This process's environment plus ``PARENT_PID_ENV`` naming it, for ``subprocess``."""
    return {**os.environ, PARENT_PID_ENV: str(os.getpid())}


def stop_with_parent() -> None:
    """Get SIGINT when the parent named in ``PARENT_PID_ENV`` dies (no-op when unset)."""
    parent = os.environ.get(PARENT_PID_ENV)
    if not parent or not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGINT), 0, 0, 0) != 0:
        return
    # The parent may have died before prctl took effect: then we were re-parented already.
    if os.getppid() != int(parent):
        os.kill(os.getpid(), signal.SIGINT)


def stop_children(children: Mapping[str, subprocess.Popen[bytes]], timeout_s: float) -> list[str]:
    """SIGINT every running child, wait up to ``timeout_s`` in all, kill what still runs.

    Returns
    -------
    list of str
        The names of the children that had to be killed.
    """
    for proc in children.values():
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + timeout_s
    killed = []
    for name, proc in children.items():
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        if proc.poll() is None:
            proc.kill()
            proc.wait()
            killed.append(name)
    return killed
