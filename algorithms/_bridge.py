"""What the bridges to other libraries' optimisers share (``ng:``, ``pymoo:``)."""

from __future__ import annotations

from heurtune.core.errors import ConfigError


def inside_library(label: str, library: str, step, *args):
    """``step(*args)``; an exception raised inside the bridged library becomes a one-line
    ConfigError naming the optimiser ``label`` and ``library`` (name and version), with the
    first line of the library's message."""
    try:
        return step(*args)
    except ConfigError:
        raise
    except Exception as exc:  # noqa: BLE001 - the library's own failure, named
        first = str(exc).splitlines()[0] if str(exc) else ""
        raise ConfigError(f"{label} failed inside {library}: {type(exc).__name__}: {first}") from exc
