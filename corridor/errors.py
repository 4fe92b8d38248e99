"""Errors a user can fix: printed as one line, exit code 2, no traceback (``--debug`` shows it)."""

from __future__ import annotations


class CorridorError(Exception):
    """Base for errors whose message alone tells the user what to fix."""


class ScenarioError(CorridorError):
    """A scenario file, override or command-line value is wrong."""


def clip(value: object, limit: int = 60) -> str:
    """``repr`` of a user value for an error message, cut to ``limit`` characters (one line, bounded)."""
    text = repr(value) if isinstance(value, str) else repr(str(value))
    return text if len(text) <= limit else text[: limit - 1] + "…"
