"""A custom message crosses real DDS: publisher and subscriber in two separate processes."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

PUBLISHER = """
import sys, time, rclpy
from rclpy.qos import qos_profile_sensor_data
from thruster_fdd_msgs.msg import EscTelemetry
rclpy.init()
node = rclpy.create_node('roundtrip_pub')
pub = node.create_publisher(EscTelemetry, '/thruster/rt/esc/telemetry', qos_profile_sensor_data)
deadline = time.monotonic() + 20
i = 0
while time.monotonic() < deadline:
    msg = EscTelemetry(thruster_id='rt', sequence=i, voltage_v=15.25, rpm=-1234.5, pwm_us=1460)
    pub.publish(msg)
    i += 1
    rclpy.spin_once(node, timeout_sec=0.02)
"""


@pytest.mark.ros
def test_telemetry_roundtrip_between_processes(ros_context: object) -> None:
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data
    from thruster_fdd_msgs.msg import EscTelemetry

    received: list[EscTelemetry] = []
    node = Node("roundtrip_sub", context=ros_context)
    node.create_subscription(
        EscTelemetry, "/thruster/rt/esc/telemetry", received.append, qos_profile_sensor_data
    )
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    publisher = subprocess.Popen([sys.executable, "-c", PUBLISHER])
    try:
        deadline = time.monotonic() + 20
        while len(received) < 5 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
    finally:
        publisher.kill()
        publisher.wait()
        executor.shutdown()
        node.destroy_node()
    assert len(received) >= 5
    msg = received[-1]
    assert msg.thruster_id == "rt"
    assert msg.voltage_v == pytest.approx(15.25)
    assert msg.rpm == pytest.approx(-1234.5)
    assert msg.pwm_us == 1460
    assert [m.sequence for m in received] == sorted(m.sequence for m in received)
