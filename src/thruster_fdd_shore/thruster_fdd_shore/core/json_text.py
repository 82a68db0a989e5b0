"""JSON text of result data whose numbers may not be finite.

``json.dumps`` writes ``Infinity`` and ``NaN``, which strict parsers (and most languages' JSON
readers) refuse, and raises on numpy scalars. :func:`json_text` walks the data first: numpy
scalars become Python numbers and each non-finite float becomes what the file's contract says
(``None`` for the discrepancy report's details.json, the text ``"inf"`` / ``"nan"`` for the
diagnosis evaluation's table3.json). No ROS import.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable

import numpy as np


def _finite(value: object, nonfinite: Callable[[float], object]) -> object:
    """``value`` with numpy scalars as Python numbers and ``nonfinite(x)`` for each float ``x``
    that is not finite, in mappings, lists and tuples at any depth (tuples become lists, as
    ``json.dumps`` writes them)."""
    if isinstance(value, dict):
        return {key: _finite(item, nonfinite) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(item, nonfinite) for item in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return nonfinite(value)
    return value


def json_text(value: object, *, nonfinite: Callable[[float], object], indent: int) -> str:
    """``value`` as JSON text ending in a newline, ``nonfinite`` standing in for every float
    that is not finite (``_finite``); a value of another type JSON lacks raises TypeError."""
    return json.dumps(_finite(value, nonfinite), indent=indent) + "\n"
