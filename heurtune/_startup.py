"""Ctrl-C and SIGTERM while a ``python -m heurtune.<command>`` imports its modules.

The imports take a second or more (numpy, pandas, numba, matplotlib). A KeyboardInterrupt raised
inside one leaves a module half initialised, and what follows fails with a misleading traceback.
:func:`guard` (called first thing by ``heurtune/__init__.py`` when the process is such a command)
turns either signal into one line on stderr and exit code 130 or 143, at once; the command's
entry point calls :func:`release` once its imports are done, and its own handling takes over.
Standard library only: this runs before anything heavy is imported.
"""

import os
import signal
import sys

_GUARDED = []


def _command() -> bool:
    """Whether this process is ``python [options] -m heurtune.<something>``."""
    argv = getattr(sys, "orig_argv", [])
    try:
        i = argv.index("-m")
    except ValueError:
        return False
    return i + 1 < len(argv) and argv[i + 1].startswith("heurtune.")


def _stop(signum, frame):
    os.write(2, b"\ninterrupted while starting; nothing was run\n")
    os._exit(130 if signum == signal.SIGINT else 143)


def guard() -> None:
    """Install the start-up handlers (once, in the main thread of a heurtune command).

    A signal the command was started with ignored (a background job of a script: ``cmd &``)
    stays ignored. A block inherited from the parent (a thread that had SIGINT or SIGTERM
    blocked when it started the command) is lifted once the handlers are in place: a blocked
    signal would wait, unseen, until the command ends by itself.
    """
    if _GUARDED or not _command():
        return
    try:
        _GUARDED.append(tuple(signal.SIG_IGN if signal.getsignal(signum) == signal.SIG_IGN
                              else signal.signal(signum, _stop) for signum in (signal.SIGINT, signal.SIGTERM)))
    except ValueError:  # not the main thread
        return
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})


def release() -> None:
    """Give SIGINT back to Python (KeyboardInterrupt) and SIGTERM to what it was."""
    if _GUARDED:
        sigint, sigterm = _GUARDED.pop()
        signal.signal(signal.SIGINT, signal.default_int_handler if sigint is None else sigint)
        signal.signal(signal.SIGTERM, signal.SIG_DFL if sigterm is None else sigterm)


def _stdout_closed() -> bool:
    """Whether the reader of stdout has gone (the pipe reports an error to a writer)."""
    import select

    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & (select.POLLERR | select.POLLHUP) for _, events in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll here, or no real stdout: assume it is
        return True


def run_command(run) -> int:
    """``run()``'s exit code, with a closed stdout taken as the reader's choice: a command
    piped into ``head`` (``--list | head``) stops quietly with exit code 0 instead of a
    BrokenPipeError traceback. A BrokenPipeError from anything but stdout is raised as it is."""
    try:
        code = run()
        sys.stdout.flush()
        return code
    except BrokenPipeError:
        if not _stdout_closed():
            raise  # stdout still works: the pipe that broke is another one
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's last flush at exit goes nowhere
        return 0
