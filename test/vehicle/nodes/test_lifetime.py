"""Node processes end: on Ctrl-C while busy, and when the process that started them is killed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from thruster_fdd.lifetime import PARENT_PID_ENV

pytestmark = pytest.mark.ros

# A parent that starts a nominal_model node as ``up`` and ``replay`` do, prints its pid, waits.
PARENT = textwrap.dedent(
    """
    import subprocess, sys, time
    from thruster_fdd.lifetime import child_env
    cmd = [sys.executable, "-m", "thruster_fdd.nodes.nominal_model", "--ros-args",
           "-r", "__ns:=/thruster/life"]
    child = subprocess.Popen(cmd, env=child_env(), stdout=subprocess.DEVNULL)
    print(child.pid, flush=True)
    time.sleep(120)
    """
)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie is gone for our purpose: it no longer runs.
    with open(f"/proc/{pid}/stat") as f:
        return f.read().split(")")[-1].split()[0] != "Z"


def _wait_gone(pid: int, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if not _alive(pid):
            return True
        time.sleep(0.1)
    return False


def test_node_stops_when_its_parent_is_killed() -> None:
    parent = subprocess.Popen([sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        child = int(parent.stdout.readline())
        time.sleep(8.0)  # torch and the model load
        assert _alive(child), "the node died on its own"
        parent.kill()
        parent.wait(timeout=10)
        assert _wait_gone(child, 15.0), "the node outlived its killed parent"
    finally:
        parent.kill()
        subprocess.run(["pkill", "-9", "-f", "__ns:=/thruster/life"], check=False)


def test_node_exits_promptly_on_ctrl_c() -> None:
    env = {k: v for k, v in os.environ.items() if k != PARENT_PID_ENV}
    cmd = [sys.executable, "-m", "thruster_fdd.nodes.nominal_model", "--ros-args"]
    cmd += ["-r", "__ns:=/thruster/life2"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL)
    try:
        time.sleep(8.0)
        assert proc.poll() is None, "the node died on its own"
        proc.send_signal(signal.SIGINT)
        # Ctrl-C: the executor is shut down before the node is destroyed, so it exits promptly.
        assert proc.wait(timeout=10) == 0
    finally:
        proc.kill()


# Ctrl-C after init_rclpy, then a stretch of Python as a teardown would run: rclpy shuts the
# context down and no KeyboardInterrupt lands in the stretch.
CTRL_C_AFTER_INIT = textwrap.dedent(
    """
    import os, signal, time
    import rclpy
    from thruster_fdd.nodes.common import init_rclpy

    init_rclpy(None)
    os.kill(os.getpid(), signal.SIGINT)
    end = time.monotonic() + 0.5
    while time.monotonic() < end:
        pass
    print("context ok" if rclpy.ok() else "context shut down")
    """
)


@pytest.mark.parametrize("init", ["init_rclpy", "rclpy.init"])
def test_ctrl_c_ends_the_context_without_a_keyboard_interrupt_in_teardown(init: str) -> None:
    script = CTRL_C_AFTER_INIT
    if init == "rclpy.init":  # the peer: Python's default handler raises in the stretch
        script = script.replace("init_rclpy(None)", "rclpy.init()")
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=30
    )
    if init == "init_rclpy":
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert proc.stdout.strip() == "context shut down"
    else:
        assert "KeyboardInterrupt" in proc.stderr


# A node whose destroy_node never returns, as rclpy's can after a Ctrl-C inside a callback.
STUCK = textwrap.dedent(
    """
    import sys
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from thruster_fdd.nodes import common

    class Stuck(Node):
        def shutdown(self):
            open(sys.argv[1], "w").write("shutdown hook ran")

        def destroy_node(self):
            while True:
                pass

    common.TEARDOWN_TIMEOUT_S = 1
    rclpy.init()
    node = Stuck("stuck")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    common.release_and_destroy([executor], [node])
    """
)


def test_a_teardown_that_hangs_ends_the_process_after_its_hooks(tmp_path: Path) -> None:
    marker = tmp_path / "hook"
    proc = subprocess.run(
        [sys.executable, "-c", STUCK, str(marker)], capture_output=True, timeout=30
    )
    assert proc.returncode == -signal.SIGALRM, proc.stderr[-2000:]
    assert marker.read_text() == "shutdown hook ran"


def test_stop_children_kills_and_names_a_child_that_ignores_ctrl_c() -> None:
    from thruster_fdd.lifetime import stop_children

    # Both say when they are up: a Ctrl-C during the interpreter's start-up is caught by site's
    # .pth handling, and the "polite" child then sleeps on (seen once on a loaded machine).
    polite = subprocess.Popen(
        [sys.executable, "-c", "import time; print('ready', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE,
    )
    stubborn = subprocess.Popen(
        [sys.executable, "-c", "import signal, time; signal.signal(signal.SIGINT, "
         "signal.SIG_IGN); print('ready', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE,
    )  # fmt: skip
    try:
        assert polite.stdout is not None
        assert stubborn.stdout is not None
        assert polite.stdout.readline() == b"ready\n"
        assert stubborn.stdout.readline() == b"ready\n"
        killed = stop_children({"polite": polite, "stubborn": stubborn}, timeout_s=2.0)
        assert killed == ["stubborn"]
        assert polite.returncode != 0
        assert stubborn.returncode == -signal.SIGKILL
    finally:
        for proc in (polite, stubborn):
            proc.kill()
            proc.wait()
