"""The ROS-free shore core: plain functions and dataclasses, one package per concern.

- ``sim``: the thruster simulator (physics, effects, configuration, command signals, scenarios).
- ``bridge``: the microcontroller emulator, HoTT ESC telemetry, the firmware build and its
  co-simulation on an emulated AVR, pseudo-terminal links, the bridge check.
- ``traces``: trace CSV, input files, replay checks.
- ``nominal``: training, evaluation and export of the nominal NARX model.
- ``diagnosis``: training and evaluation of the classifier, offline diagnosis, Table 3.
- ``discrepancy``: what the simulator misses against a measurement.
- ``reference``: the reference load curves the health node reads.

No module here imports rclpy or a ROS message package (``test/test_workspace.py`` checks).
"""
