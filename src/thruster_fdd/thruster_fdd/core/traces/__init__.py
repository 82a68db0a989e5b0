"""Telemetry traces and recordings (docs/contracts.md, "MCAP").

``data`` is the ``Trace`` container; ``mcap_io`` and ``mcap_read`` write and read it as MCAP;
``recording`` is the recorder's MCAP writer.
"""
