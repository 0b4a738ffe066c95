"""Several optimisation runs advanced in lockstep, their evaluations gathered into one batch.

Each run keeps its own thread, generator, optimiser and termination, exactly as when it runs
alone; only its evaluator is replaced by a :class:`Client` of a shared :class:`Lockstep`. A
client's call blocks until every run that is still going has asked for something too; then the
requests of all runs are evaluated together, one batch per problem, and each run gets its own
rows back. Since a candidate's evaluation does not depend on the other candidates of its batch
(the one-candidate kernel trivially, the batched kernels by construction and test), every run
computes exactly what it would alone on the same device, whatever the number of runs or
workers.

A driver's ``map_unordered`` (e.g. the local solves of ``sqp_multistart``) runs each item in a
thread of its own that takes part in the lockstep, so the local solves of all runs share the
batches too. The runs' threads must reach the problem only through their client: evaluations
happen in the driving thread alone (the problems' simulators keep scratch state), which is why
the experiment runner records each finished run there, not in the run's thread. BLAS is held
at one thread while runs are in lockstep: threadpoolctl's limits are process-wide, so a thread
leaving its own limit (as ``sqp_multistart``'s local solves do) would otherwise give the other
threads more BLAS threads mid-computation, and with them other last bits.

Python threads only take turns (the GIL); the point is the batch, which the evaluator then
spreads over its workers or hands to a batched kernel.
"""

from __future__ import annotations

import itertools
import queue
import threading

import numpy as np

__all__ = ["Lockstep", "Client", "LockstepAborted"]


class LockstepAborted(Exception):
    """Raised in a run's thread when the lockstep stops early (another run failed, or Ctrl-C)."""


class Client:
    """What a run sees as its evaluator: ``client(X) -> (f, g)`` through the lockstep.

    It offers what :class:`heurtune.core.engine.RunContext` uses of an evaluator: the call,
    ``objective`` (for a driver's tasks) and ``pool.imap_unordered`` (for a driver's work units).
    """

    def __init__(self, hub: Lockstep, group):
        self.hub = hub
        self.group = group

    def __call__(self, X):
        return self.hub.submit(self.group, X)

    @property
    def objective(self):
        return self

    @property
    def pool(self):
        return self

    workers = 1

    def imap_unordered(self, fn, items):
        """Run ``fn(item)`` for every item, each in a thread of the lockstep, at most
        :attr:`Lockstep.fan_out_width` at once; yield ``(index, result)`` as each ends
        (:meth:`Lockstep.fan_out`)."""
        return self.hub.fan_out(fn, items)


class Lockstep:
    """Gathers the evaluations of the runs it drives (see the module docstring).

    Parameters
    ----------
    evaluate : callable
        ``evaluate({group: X}) -> {group: (f, g)}``: a batch per group (e.g. the runs' case),
        all evaluated in one go.
    """

    #: Items of one :meth:`fan_out` that run at once (the local solves of one multistart run).
    fan_out_width = 32

    def __init__(self, evaluate):
        self._evaluate = evaluate
        self._cond = threading.Condition()
        self._clients = 0  # threads that may still ask for evaluations
        self._tickets = itertools.count()
        self._requests = {}  # ticket -> (group, X), while its thread waits
        self._answers = {}
        self._events = {}  # ticket -> the event its thread waits on
        self._finished = []  # (index, result, error) of ended runs
        self._abort = False
        self.batches = []  # sizes of the batches evaluated (for tests and reports)

    def client(self, group) -> Client:
        return Client(self, group)

    # -- the runs' side ----------------------------------------------------------------------
    def submit(self, group, X):
        """Wait until every running thread has asked too, then return this request's (f, g).

        Each request waits on an event of its own (only the driving thread waits on the
        condition), so that an answer wakes one thread, not all of them."""
        X = np.ascontiguousarray(X, dtype=np.float64)
        answered = threading.Event()
        with self._cond:
            if self._abort:
                raise LockstepAborted
            ticket = next(self._tickets)
            self._requests[ticket] = (group, X)
            self._events[ticket] = answered
            self._cond.notify_all()
        answered.wait()
        with self._cond:
            if ticket not in self._answers:  # woken by an abort
                raise LockstepAborted
            return self._answers.pop(ticket)

    def _join(self, n: int) -> None:
        with self._cond:
            self._clients += n
            self._cond.notify_all()

    def fan_out(self, fn, items):
        """Run ``fn(item)`` for every item in threads that take part in the lockstep (the
        calling thread steps out of it meanwhile); yield ``(index, result)`` as each ends.

        At most :attr:`fan_out_width` items run at once; the next starts as one ends. A
        consumer that stops early (a multistart run whose ``max_epochs`` is reached) starts
        no further item: the generator waits for the running ones and returns. Each item's
        result does not depend on which others share its batches, so the width changes only
        the batches' sizes, never a result."""
        items = list(items)
        if not items:
            return
        ended = queue.SimpleQueue()

        def work(i, item):
            result, error = None, None
            try:
                result = fn(item)
            except BaseException as exc:  # noqa: BLE001 - re-raised in the calling thread
                error = exc
            self._join(-1)
            ended.put((i, result, error))

        def start(i):
            threading.Thread(target=work, args=(i, items[i]), daemon=True).start()

        first = min(self.fan_out_width, len(items))
        self._join(first - 1)  # the first items in, the caller out, in one step
        for i in range(first):
            start(i)
        launched, running = first, first
        try:
            while running:
                i, result, error = ended.get()
                running -= 1
                if error is not None:
                    raise error
                yield i, result
                if launched < len(items):
                    self._join(1)
                    start(launched)
                    launched += 1
                    running += 1
        finally:  # stopped early, or an item failed: let the running items end
            while running:
                ended.get()
                running -= 1
            self._join(1)

    # -- the driving side --------------------------------------------------------------------
    def run(self, targets):
        """Run ``targets`` (callables, one per run) in lockstep; yield ``(index, result)`` as
        each run ends. An error in a run stops the others and is raised here."""
        from threadpoolctl import threadpool_limits

        targets = list(targets)
        with threadpool_limits(1, user_api="blas"):
            yield from self._run(targets)

    def _run(self, targets):
        def work(i, target):
            result, error = None, None
            try:
                result = target()
            except BaseException as exc:  # noqa: BLE001 - raised in the driving thread
                error = exc
            with self._cond:
                self._finished.append((i, result, error))
                self._clients -= 1
                self._cond.notify_all()

        self._clients = len(targets)
        threads = [threading.Thread(target=work, args=(i, t), daemon=True) for i, t in enumerate(targets)]
        for t in threads:
            t.start()
        ended = 0
        try:
            while ended < len(targets):
                with self._cond:
                    while not (self._finished or (self._requests and len(self._requests) >= self._clients)):
                        self._cond.wait()
                    finished, self._finished = self._finished, []
                    requests = {} if finished else dict(self._requests)
                    for ticket in requests:
                        del self._requests[ticket]
                for i, result, error in finished:
                    if error is not None:
                        raise error
                    ended += 1
                    yield i, result
                if requests:
                    answers = self._answer(requests)
                    with self._cond:
                        self._answers.update(answers)
                        for ticket in answers:
                            self._events.pop(ticket).set()
        finally:
            with self._cond:
                if ended < len(targets):
                    self._abort = True
                    for event in self._events.values():
                        event.set()
                self._cond.notify_all()

    def _answer(self, requests: dict) -> dict:
        """Evaluate the waiting requests, one batch per group (in ticket order)."""
        by_group = {}
        for ticket in sorted(requests):
            group, X = requests[ticket]
            by_group.setdefault(group, []).append((ticket, X))
        batches = {group: np.vstack([x for _, x in members]) for group, members in by_group.items()}
        self.batches += [X.shape[0] for X in batches.values()]
        results = self._evaluate(batches)
        answers = {}
        for group, members in by_group.items():
            f, g = results[group]
            start = 0
            for ticket, x in members:
                stop = start + x.shape[0]
                answers[ticket] = (f[start:stop], g[start:stop])
                start = stop
        return answers
