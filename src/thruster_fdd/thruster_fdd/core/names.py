"""Thruster ids as ROS names: what ``up``, its config and the nodes accept before a node is made.

A thruster's nodes live in the namespace ``/thruster/<id>`` and its topics under it, so an id
must be one ROS name token (ASCII letters, digits and underscores, not starting with a digit)
and short enough for every name made from it.
"""

from __future__ import annotations

import re

from thruster_fdd.core.errors import BadInputError

MAX_THRUSTER_ID_LENGTH = 64
"""Longest thruster id (ROS namespaces are limited to about 200 characters, topics below)."""

_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def check_thruster_id(value: object) -> str:
    """``value`` when it is a valid thruster id, else BadInputError saying why (one line).

    Parameters
    ----------
    value : object
        The id as given (config, command line, parameter).

    Returns
    -------
    str
        The id.

    Raises
    ------
    BadInputError
        If ``value`` is not a string, is not one ROS name token (``str.isidentifier`` admits
        non-ASCII letters such as ``tä``, which ROS refuses) or is longer than
        ``MAX_THRUSTER_ID_LENGTH``.
    """
    if not isinstance(value, str) or _TOKEN.fullmatch(value) is None:
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
        raise BadInputError(
            f"thruster id {shown} must be a ROS name token like t0 "
            "(ASCII letters, digits, underscores; not starting with a digit)"
        )
    if len(value) > MAX_THRUSTER_ID_LENGTH:
        raise BadInputError(
            f"thruster id {value[:20]!r}... is {len(value)} characters, at most "
            f"{MAX_THRUSTER_ID_LENGTH}"
        )
    return value
