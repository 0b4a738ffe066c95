"""Exceptions raised by heurtune for user-facing mistakes, and the one-line config warnings."""

import contextlib
import sys
import threading

__all__ = ["ConfigError", "DesignError", "config_warning", "quiet_config_warnings"]


class ConfigError(ValueError):
    """A configuration, preset or input is invalid; the message is one line naming the key."""


class DesignError(RuntimeError):
    """One candidate's controller cannot be built (a family's design step failed). Problems
    turn it into a failed, finite candidate; ``simulate`` and the commands report it in one line."""


_QUIET = threading.local()


def config_warning(message: str) -> None:
    """Print ``warning: message`` on stderr: a config that loads but has a key it will not use.

    Silent inside :func:`quiet_config_warnings` (a worker rebuilding a config that the command
    has already loaded, and warned about, once).

    Parameters
    ----------
    message : str
        One line, without the ``warning:`` prefix.
    """
    if not getattr(_QUIET, "on", False):
        print(f"warning: {message}", file=sys.stderr)


@contextlib.contextmanager
def quiet_config_warnings():
    """Within the block, :func:`config_warning` prints nothing (in this thread)."""
    before = getattr(_QUIET, "on", False)
    _QUIET.on = True
    try:
        yield
    finally:
        _QUIET.on = before
