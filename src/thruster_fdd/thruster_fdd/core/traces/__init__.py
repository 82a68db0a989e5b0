"""Telemetry traces and recordings (docs/contracts.md, "Trace CSV" and "MCAP").

``data`` is the ``Trace`` container; ``csv_io`` and ``mcap_io`` read and write it as trace CSV
and MCAP; ``files`` reads files and folders of either; ``recording`` is the recorder's MCAP
writer; ``replay_check`` says what a replay publishes and judges what came back.
"""
