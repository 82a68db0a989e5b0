"""Domain exceptions: what a user gave is wrong, as opposed to a bug.

The command line turns these into exit code 2 and one line naming the input and what is wrong;
any other exception is a bug and keeps its traceback. Both subclass ``ValueError``, so code that
validates with ``ValueError`` semantics (and tests that expect it) keep working.
"""

from __future__ import annotations


class BadInputError(ValueError):
    """An input (file, option, configuration, message) is not acceptable; the text says why."""


class ModelMismatchError(BadInputError):
    """An exported model does not fit: missing or corrupt files, another kind, a card that
    disagrees with its program, or a classifier made with another nominal model."""


class PartialInputWarning(UserWarning):
    """An input was used only in part (a damaged recording, samples left out); the text says
    what was left out and how much. The command line prints it as one line."""
