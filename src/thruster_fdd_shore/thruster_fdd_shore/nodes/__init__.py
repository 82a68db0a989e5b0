"""Nodes of the simulation harness and the tools: the command player, the live table's monitor,
the probe, the lifecycle client ``up`` and ``reload`` use."""
