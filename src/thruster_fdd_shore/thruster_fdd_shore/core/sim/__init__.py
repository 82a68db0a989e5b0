"""The thruster simulator (docs/simulator.md).

``physics`` steps one thruster (``ThrusterSimulator``, ``simulate``); ``plant`` holds what a
condition does to a unit; ``effects`` and ``config`` are the named effects and the YAML
configuration (presets in ``presets/``); ``freerun`` is the compiled noise-free run the
discrepancy workflow fits with; ``steady`` and ``metrics`` give static curves and step / loop
measures; ``signals`` and ``scenario`` make command histories and whole runs.
"""
