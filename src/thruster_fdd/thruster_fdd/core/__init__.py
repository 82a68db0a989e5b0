"""The ROS-free core of the vehicle package: what the nodes run, and nothing else.

- ``bridge``: the serial bridge (CRCs, the tfdd protocol, KISS telemetry, plausibility, serial
  ports, the driver's link logic).
- ``traces``: telemetry traces and the recorder's MCAP writer and reader.
- ``nominal``: the nominal NARX model's runtime and residuals.
- ``diagnosis``: the classifier's runtime and online decisions, reference curves, effectiveness
  and health.

At this level: ``labels`` (the canonical class names), ``errors`` (bad input vs. a bug),
``artifact`` (exported model folders and their cards), ``atomic`` (files that appear whole) and
``safe_yaml``. No module here imports rclpy or a ROS message package, nor anything of the shore
package (``test/test_workspace.py`` checks); the contracts are in ``docs/contracts.md``.
"""
