"""Exceptions raised by heurtune for user-facing mistakes."""

__all__ = ["ConfigError", "DesignError"]


class ConfigError(ValueError):
    """A configuration, preset or input is invalid; the message is one line naming the key."""


class DesignError(RuntimeError):
    """One candidate's controller cannot be built (a family's design step failed). Problems
    turn it into a failed, finite candidate; ``simulate`` and the commands report it in one line."""
