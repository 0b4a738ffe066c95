"""Exceptions raised by heurtune for user-facing mistakes."""

__all__ = ["ConfigError"]


class ConfigError(ValueError):
    """A configuration, preset or input is invalid; the message is one line naming the key."""
