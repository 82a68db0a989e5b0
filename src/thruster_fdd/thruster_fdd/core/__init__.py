"""The ROS-free core of thruster_fdd: plain functions and dataclasses, one package per concern.

- ``sim``: the thruster simulator (physics, effects, configuration, command signals, scenarios).
- ``bridge``: the serial bridge (CRCs, the tfdd protocol, KISS telemetry, plausibility, the
  microcontroller emulator, the driver's link logic).
- ``traces``: telemetry traces and recordings (trace CSV, MCAP, the recorder's writer, replay
  checks).
- ``nominal``: the nominal NARX model (networks, training, evaluation, export, runtime step,
  residuals).
- ``diagnosis``: the fault classifier (window features, model, online stream, offline
  diagnosis, training, evaluation).
- ``discrepancy``: what the simulator misses against a measurement (measure, fit, search,
  synthetic cases, report).

At this level: ``labels`` (the canonical class names), ``errors`` (bad input vs. a bug),
``artifact`` (exported model folders and their cards) and ``atomic`` (files that appear whole).
No module here imports rclpy or a ROS message package (``test/test_workspace.py`` checks); the
contracts the code relies on are in ``docs/contracts.md``.
"""
