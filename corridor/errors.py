"""Errors a user can fix: printed as one line, exit code 2, no traceback (``--debug`` shows it)."""

from __future__ import annotations


class CorridorError(Exception):
    """Base for errors whose message alone tells the user what to fix."""


class ScenarioError(CorridorError):
    """A scenario file, override or command-line value is wrong.

    The message is kept to one line of at most ``MAX_MESSAGE`` characters whatever it quotes (the
    raising code clips the user values it echoes; this is the last guard).
    """

    MAX_MESSAGE = 299

    def __init__(self, message: object = "") -> None:
        text = " ".join(str(message).split("\n"))
        if len(text) > self.MAX_MESSAGE:
            text = text[: self.MAX_MESSAGE - 1] + "…"
        super().__init__(text)


def clip(value: object, limit: int = 60) -> str:
    """``repr`` of a user value for an error message, cut to ``limit`` characters (one line, bounded)."""
    text = repr(value) if isinstance(value, str) else repr(str(value))
    return text if len(text) <= limit else text[: limit - 1] + "…"


def clip_path(path: object, limit: int = 80) -> str:
    """``repr`` of a file path for an error message, cut at its start so the file's name stays."""
    text = repr(str(path))
    return text if len(text) <= limit else repr("…" + str(path)[-(limit - 3):])
