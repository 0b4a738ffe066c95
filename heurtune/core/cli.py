"""What every ``python -m heurtune.<command>`` has in common: its exit codes, stated in ``--help``."""

from __future__ import annotations

import argparse

from heurtune.core.errors import ConfigError

__all__ = ["EXIT_CODES", "exit_codes", "UsageError", "OneLineParser", "parse_labels"]

EXIT_CODES = {
    0: "done",
    2: "a bad config, option, input or output path, or a disk error: one line on stderr names it and "
       "nothing half-written is left",
}


def exit_codes(examples=(), **extra: str) -> str:
    """The ``--help`` epilog: examples of the command, then its exit codes (:data:`EXIT_CODES`
    and ``extra``, keyword ``c<code>``, e.g. ``c130="interrupted"``).

    A parser that shows examples keeps the epilog's lines: give it
    ``formatter_class=argparse.RawDescriptionHelpFormatter``.

    Parameters
    ----------
    examples : sequence of str
        Command lines, one per line of the epilog.
    **extra : str
        More codes, keyword ``c<code>`` (``c130="interrupted"``).

    Returns
    -------
    str
    """
    codes = dict(EXIT_CODES)
    codes.update({int(k.lstrip("c")): v for k, v in extra.items()})
    text = "exit codes: " + "; ".join(f"{code} {what}" for code, what in sorted(codes.items()))
    if examples:
        import textwrap

        text = "examples:\n" + "\n".join(f"  {e}" for e in examples) + "\n\n" + textwrap.fill(text, 100)
    return text


class UsageError(Exception):
    """A command-line mistake, reported as one line (exit code 2)."""


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors raise :class:`UsageError` instead of printing usage."""

    def error(self, message):  # one line instead of usage + message
        raise UsageError(message)


def parse_labels(items) -> dict:
    """The ``--label`` options as a mapping.

    Parameters
    ----------
    items : iterable of str
        ``"NAME=DIR"`` each.

    Returns
    -------
    dict
        ``{NAME: DIR}``.

    Raises
    ------
    ConfigError
        A missing ``=``, or a NAME given twice.
    """
    out = {}
    for item in items:
        name, sep, d = item.partition("=")
        name = name.strip()
        if not sep or not name or not d:
            raise ConfigError(f"--label '{item}' must have the form NAME=DIR")
        if name in out:
            raise ConfigError(f"--label name '{name}' is given twice ({out[name]} and {d})")
        out[name] = d
    return out
