"""Errors a user can fix: printed as one line, exit code 2, no traceback (``--debug`` shows it)."""

from __future__ import annotations


class CorridorError(Exception):
    """Base for errors whose message alone tells the user what to fix."""


class ScenarioError(CorridorError):
    """A scenario file, override or command-line value is wrong."""
