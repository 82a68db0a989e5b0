"""Command player node: drives one thruster with a command signal (a mission stand-in).

Publishes ``ThrusterCommand`` on ``esc/command`` following a signal of ``core.sim.signals``
(steps, sine:F, chirp, multilevel, mission), looping when it ends. ``thruster-fdd up`` starts one
per simulated thruster so the telemetry shows a thruster at work.
"""

from __future__ import annotations

from typing import Any

from rclpy.node import Node
from thruster_fdd_msgs.msg import ThrusterCommand

from thruster_fdd.nodes.common import NO_PUB_EVENTS, RELIABLE_10, declare_parameters, run
from thruster_fdd_shore.core.sim.signals import make_signal

PARAMETERS: tuple[tuple[str, object, str], ...] = (
    ("signal", "mission", "command signal: steps | sine:F | chirp | multilevel | mission"),
    ("duration_s", 600.0, "length of the signal before it loops, s"),
    ("rate_hz", 20.0, "command publishing rate, Hz"),
    ("seed", 0, "seed of random signals (multilevel, mission)"),
)


class CommandPlayer(Node):
    """Publishes a precomputed command signal at a fixed rate (see module docstring)."""

    def __init__(self, **node_kwargs: Any) -> None:
        super().__init__("command_player", **node_kwargs)
        declare_parameters(self, PARAMETERS)
        p = self.get_parameter
        rate = float(p("rate_hz").value)
        _, self._commands = make_signal(
            p("signal").value, float(p("duration_s").value), rate, seed=int(p("seed").value)
        )
        self._index = 0
        self._pub = self.create_publisher(
            ThrusterCommand, "esc/command", RELIABLE_10, event_callbacks=NO_PUB_EVENTS
        )
        self.create_timer(1.0 / rate, self._tick)

    def _tick(self) -> None:
        msg = ThrusterCommand(command=float(self._commands[self._index]))
        msg.header.stamp = self.get_clock().now().to_msg()
        self._pub.publish(msg)
        self._index = (self._index + 1) % len(self._commands)


def main(args: list[str] | None = None) -> None:
    """Run the node until Ctrl-C (the ESC driver's watchdog then brings the thruster to neutral)."""
    run(CommandPlayer, args)


if __name__ == "__main__":
    main()
