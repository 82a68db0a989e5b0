"""The serial link between the ESC driver and the thruster's microcontroller (docs/protocol.md).

``tfdd`` is the project's bridge protocol (frames, encoders, streaming decoder, sequence rule),
``kiss`` the KISS / BLHeli_32 ESC telemetry, ``crc`` their checksums, ``plausibility`` what the
driver refuses to publish, ``ports`` the serial ports, ``link`` the driver's logic without ROS
(command shaping, watchdog, link health), ``sequence`` and ``stuck`` the sequence and stuck-value
checks.
"""
