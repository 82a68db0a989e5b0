"""The canonical condition names every part of the package spells the same way.

The six classes are the ``condition`` column of a trace CSV, the classes of a model card and the
``label`` of a ``Diagnosis`` message (docs/contracts.md, "Canonical names").
"""

from __future__ import annotations

CLASS_NAMES: tuple[str, ...] = (
    "nominal_15v",
    "nominal_13v",
    "nominal_11v8",
    "broken_blade_1",
    "broken_blade_2",
    "biofouling",
)
"""The six conditions (trace CSV ``condition`` column, model cards, ``Diagnosis.label``)."""


UNKNOWN = "unknown"
"""Label of a window unlike every class (or not confident enough)."""


FAULT_CLASSES: tuple[str, ...] = ("broken_blade_1", "broken_blade_2", "biofouling")
"""The classes that are faults (the others are healthy thrusters at some supply voltage)."""

if not set(FAULT_CLASSES) < set(CLASS_NAMES):
    raise RuntimeError("FAULT_CLASSES must be classes of CLASS_NAMES")
