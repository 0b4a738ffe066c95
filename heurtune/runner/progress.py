"""The progress line of an experiment, fed from inside running runs.

A run reports its evaluations and best-so-far at the end of every epoch (the engine's
``progress`` hook) to a :class:`Heartbeat`: a small JSON file ``parts/<run>.progress.json``,
written atomically at most once a second, wherever the run executes (this process, a loky
worker, a Dask worker sharing the folder; elsewhere it gives up quietly). :class:`Progress`
reads the heartbeats of the runs in flight once a second and redraws one line::

    [######..................] 5/20 runs, 26,410/101,000 evals, 410 evals/s, 3 min 02 s left, best min: 4254.28 [cs]

Runs done count their actual evaluations, runs in flight their heartbeat, runs to come their
planned evaluations (:func:`heurtune.runner.workplan.planned_evaluations`); the time left is
the evaluations left at this invocation's measured rate, counted from the first evaluations
seen (before that, at the rate the calibration predicted). On a terminal the line is redrawn in
place; into a file or pipe it is written when a run ends and every ``log_interval`` seconds in
between.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import threading
import time
from pathlib import Path

from heurtune.core.io import atomic_path
from heurtune.runner.workplan import format_duration

__all__ = ["Heartbeat", "Progress", "clear_heartbeats", "HEARTBEAT_SUFFIX"]

HEARTBEAT_SUFFIX = ".progress.json"
# The measured rate is shown (and used for the time left) once evaluations have been seen for
# this long; before, the time left comes from the calibration.
RATE_AFTER_S = 3.0


class Heartbeat:
    """The engine's ``progress`` hook of one run: writes ``path`` at most every ``interval`` s.

    Picklable (it travels with the run to its worker). Writing is best-effort: a worker that
    cannot write there (a Dask worker on another machine) stops trying; the run goes on.
    """

    def __init__(self, path, interval: float = 1.0):
        self.path = str(path)
        self.interval = interval
        self._last = -math.inf
        self._broken = False

    def __call__(self, n_evals: int, epoch: int, best_f: float, best_violation: float) -> None:
        now = time.monotonic()
        if self._broken or now - self._last < self.interval:
            return
        self._last = now
        if not Path(self.path).parent.is_dir():  # a worker that does not share the folder
            self._broken = True
            return
        try:
            with atomic_path(Path(self.path)) as tmp:
                tmp.write_text(json.dumps(dict(n_evals=int(n_evals), epoch=int(epoch), best_f=float(best_f),
                                               best_violation=float(best_violation))))
        except OSError:
            self._broken = True

    def __getstate__(self):
        return dict(path=self.path, interval=self.interval)

    def __setstate__(self, state):
        self.__init__(state["path"], state["interval"])


def _read(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):  # not written yet, or removed as the run ended
        return None


class Progress:
    """One status line: runs and evaluations done of the total, the rate and the time left,
    and the best so far per case over every run, those of an earlier invocation and those
    still running included.

    Parameters
    ----------
    total, done : int
        Runs planned, and runs already done before this invocation.
    stream : file
        Where the line goes (a terminal gets it redrawn in place).
    finished_rows : iterable of mappings
        The result rows of the runs already done (their ``case``, ``algorithm``, ``feasible``,
        ``best_f``, ``violation``, ``n_evals``).
    planned : dict, optional
        Part name to ``(case, algorithm, planned evaluations or None)`` of every run still to
        do; without it the line counts runs only.
    parts : path, optional
        The ``parts/`` folder whose heartbeats :meth:`start` watches.
    predicted_rate : float, optional
        Evaluations per second the calibration predicts (for the time left before any is
        measured).
    log_interval : float
        Seconds between lines when the stream is not a terminal.
    """

    def __init__(self, total: int, done: int, stream=None, finished_rows=(), *, planned=None,
                 parts=None, predicted_rate=None, log_interval: float = 30.0):
        self.total, self.done = total, done
        stream = sys.stdout if stream is None else stream  # the current one, not the import's
        self.stream = stream
        self.tty = stream.isatty()
        self.best = {}
        self.kept_evals = 0
        self.evals = 0  # of runs finished in this invocation
        self.spent = {}  # (case, algorithm) -> evaluations of its finished runs
        for row in finished_rows:  # runs kept from before a resume
            self._offer(row["case"], row["algorithm"], row["feasible"], row["best_f"], row["violation"])
            self.kept_evals += int(row["n_evals"])
            self.spent.setdefault((row["case"], row["algorithm"]), []).append(int(row["n_evals"]))
        self.planned = dict(planned or {})
        self.parts = None if parts is None else Path(parts)
        self.predicted_rate = predicted_rate
        self.log_interval = log_interval
        self.in_flight = {}  # part name -> last heartbeat
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None
        self._last_line = time.perf_counter()
        self._first = None  # (time, evaluations) when this invocation's first ones were seen

    # -- bests ------------------------------------------------------------------------------
    def _offer(self, case, algorithm, feasible, best_f, violation) -> None:
        cand = (not feasible, best_f if feasible else violation)
        if case not in self.best or cand < self.best[case][0]:
            self.best[case] = (cand, algorithm)

    def _bests(self) -> dict:
        best = dict(self.best)
        for name, beat in self.in_flight.items():
            if name not in self.planned or not math.isfinite(beat["best_violation"]):
                continue
            case, algorithm, _ = self.planned[name]
            feasible = beat["best_violation"] <= 0
            cand = (not feasible, beat["best_f"] if feasible else beat["best_violation"])
            if case not in best or cand < best[case][0]:
                best[case] = (cand, algorithm)
        return best

    # -- counts -----------------------------------------------------------------------------
    def evaluations(self) -> tuple:
        """``(done, total)``: evaluations spent so far (earlier invocations included) and the
        total expected. A run to come with no count known in advance counts the mean of the
        finished runs of its case and optimiser; total is None until there is one."""
        running = sum(b["n_evals"] for b in self.in_flight.values())
        done = self.kept_evals + self.evals + running
        if not self.planned and not self.in_flight:
            return done, done if self.done >= self.total else None
        total = self.kept_evals + self.evals
        for name, (case, algorithm, planned) in self.planned.items():
            if planned is None:  # no count known in advance: that of its finished siblings
                siblings = self.spent.get((case, algorithm))
                if not siblings:
                    return done, None
                planned = int(round(sum(siblings) / len(siblings)))
            beat = self.in_flight.get(name)
            total += max(planned, beat["n_evals"]) if beat else planned
        return done, total

    def _line(self) -> str:
        width = 24
        filled = int(width * self.done / max(self.total, 1))
        parts = [f"[{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total} runs"]
        done, total = self.evaluations()
        parts.append(f"{done:,}/{total:,} evals" if total is not None else f"{done:,} evals")
        rate = self._rate(done - self.kept_evals)
        if rate or done == self.kept_evals:
            parts.append(f"{rate:.0f} evals/s" if rate else "starting")
        if total is not None and self.done < self.total:
            pace = rate or self.predicted_rate
            if pace:
                parts.append(f"{format_duration(max(total - done, 0) / pace)} left")
        bests = ", ".join(f"{c}: {v[0][1]:.6g}{'' if not v[0][0] else ' (infeasible)'} [{v[1]}]"
                          for c, v in self._bests().items())
        if bests:
            parts.append(f"best {bests}")
        return ", ".join(parts)

    def _rate(self, spent: int) -> float | None:
        """Evaluations per second of this invocation, counted from the first one seen (so that
        the workers' start-up does not count), once it has run for ``RATE_AFTER_S``."""
        now = time.perf_counter()
        if spent <= 0:
            return None
        if self._first is None:
            self._first = (now, spent)
        t_first, spent_first = self._first
        if now - t_first < RATE_AFTER_S or spent <= spent_first:
            return None
        return (spent - spent_first) / (now - t_first)

    def _columns(self) -> int:
        """The terminal's width (its own when the stream has one; ``COLUMNS`` or 80 else)."""
        try:
            return os.get_terminal_size(self.stream.fileno()).columns
        except (AttributeError, OSError, ValueError):
            return shutil.get_terminal_size(fallback=(80, 24)).columns

    def _write(self) -> None:
        line = self._line()
        if self.tty:
            # one column short of the width, padded over the previous frame: a line as long as
            # the terminal would wrap, and each redraw would leave a copy above
            width = max(self._columns() - 1, 20)
            self.stream.write("\r" + line[:width].ljust(width))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
        self._last_line = time.perf_counter()

    # -- events -----------------------------------------------------------------------------
    def update(self, row: dict, name: str | None = None):
        """A run has finished with result ``row`` (its part name ``name``)."""
        with self._lock:
            self.done += 1
            self.evals += int(row["n_evals"])
            self._offer(row["case"], row["algorithm"], row["feasible"], row["best_f"], row["violation"])
            self.spent.setdefault((row["case"], row["algorithm"]), []).append(int(row["n_evals"]))
            if name is not None:
                self.planned.pop(name, None)
                self.in_flight.pop(name, None)
            self._write()

    def poll(self) -> None:
        """Read the heartbeats of the runs in flight; redraw the line on a terminal, or write it
        when ``log_interval`` has passed."""
        if self.parts is None:
            return
        beats = {}
        for path in self.parts.glob("*" + HEARTBEAT_SUFFIX):
            name = path.name[:-len(HEARTBEAT_SUFFIX)]
            beat = _read(path)
            if beat is not None and name in self.planned:
                beats[name] = beat
        with self._lock:
            self.in_flight = {n: b for n, b in beats.items() if n in self.planned}
            done, _ = self.evaluations()
            self._rate(done - self.kept_evals)  # starts the clock of the measured rate
            if self.tty or time.perf_counter() - self._last_line >= self.log_interval:
                self._write()

    def start(self, interval: float = 1.0) -> None:
        """Watch the heartbeats every ``interval`` seconds in a background thread."""
        if self.parts is None or self._thread is not None:
            return

        def watch():
            while not self._stop.wait(interval):
                try:
                    self.poll()
                except (OSError, ValueError):  # the stream was closed under us: stop watching
                    return

        self._thread = threading.Thread(target=watch, name="heurtune-progress", daemon=True)
        self._thread.start()

    def close(self):
        """Stop watching; end the terminal's line (once, however often it is called)."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self.tty:
            self.stream.write("\n")


def clear_heartbeats(parts) -> None:
    """Remove heartbeats left by an earlier, interrupted invocation (a run that restarts from
    scratch would otherwise count its old evaluations), and their temporary files.

    Parameters
    ----------
    parts : str or Path
        The results folder's ``parts/``.
    """
    parts = Path(parts)
    for path in [*parts.glob("*" + HEARTBEAT_SUFFIX), *parts.glob(".*.progress.*.json")]:
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass
