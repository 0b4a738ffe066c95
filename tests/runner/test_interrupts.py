"""Ctrl-C and SIGTERM stop an experiment at once, keep its finished runs and leave no process behind.

Each case starts ``python -m heurtune.experiment`` in a session of its own, waits for a line of
its output (the start line: the workers are starting; a run's progress line: mid-run; the last
progress line: the final gathering), sends the signal and checks the exit status, the one line
on stderr, that no process of the session is left, and that the same command resumes.
"""

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time

import pandas as pd
import pytest

ARGS = ["cs_folqi_qtp", "--runs", "2", "--max-epochs", "4", "--jobs", "2", "--seed", "5"]


# The command starts as a shell starts a foreground command: SIGINT and SIGTERM at their default
# and not blocked, whatever this test process inherited; with ``blocked``, both blocked, as a
# thread that blocks them (loky's while it starts its resource tracker) would pass them on.
LAUNCH = ("import os, signal, sys\n"
          "for s in (signal.SIGINT, signal.SIGTERM):\n"
          "    signal.signal(s, signal.SIG_DFL)\n"
          "signal.pthread_sigmask(signal.SIG_SETMASK, {signal.SIGINT, signal.SIGTERM} if sys.argv[1] == 'blocked' "
          "else set())\n"
          "os.execv(sys.executable, [sys.executable, *sys.argv[2:]])\n")


def start(out, *extra, blocked=False):
    return subprocess.Popen([sys.executable, "-c", LAUNCH, "blocked" if blocked else "default",
                             "-m", "heurtune.experiment", *ARGS, *extra, "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def wait_for(proc, text, timeout=120.0):
    """Read stdout until a line containing ``text``; the lines so far."""
    lines = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        if text in line:
            return lines
    raise AssertionError(f"no line with {text!r} in {lines}")


def session_alive(pgid) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def signal_masks(pid) -> str:
    """The blocked, ignored and caught signal masks of ``pid``'s main thread (Linux /proc), for
    a failure message: a signal that was lost is blocked or ignored there, or not caught."""
    with contextlib.suppress(OSError):
        with open(f"/proc/{pid}/status") as fh:
            return " ".join(line.strip().replace(":\t", "=") for line in fh
                            if line.startswith(("SigBlk:", "SigIgn:", "SigCgt:")))
    return "no /proc"


def interrupt(proc, sig):
    """Send ``sig``; return (exit status, stderr, seconds to exit, the process's signal masks
    when the signal was sent); check no process is left."""
    masks = signal_masks(proc.pid)
    t0 = time.monotonic()
    os.kill(proc.pid, sig)
    err = []
    reader = threading.Thread(target=lambda: err.append(proc.stderr.read()), daemon=True)
    reader.start()
    code = proc.wait(timeout=30)
    elapsed = time.monotonic() - t0
    proc.stdout.read()
    reader.join(timeout=10)
    deadline = time.monotonic() + 10
    while session_alive(proc.pid) and time.monotonic() < deadline:  # workers killed, not waited for
        time.sleep(0.1)
    assert not session_alive(proc.pid), "a process of the experiment is still running"
    return code, "".join(err), elapsed, masks


def interrupted_line(stderr):
    lines = [line for line in stderr.splitlines() if line.startswith("interrupted")]
    assert len(lines) == 1, stderr
    return lines[0]


@pytest.mark.long  # 40 s on the EPYC: `make test` interrupts the lockstep runs and blocked signals below
def test_interrupts_at_start_mid_run_and_at_the_end_then_resume(tmp_path):
    out = tmp_path / "r"
    # 1. Ctrl-C while the workers start
    proc = start(out)
    wait_for(proc, "runs to do")
    code, err, elapsed, masks = interrupt(proc, signal.SIGINT)
    assert code == 130 and elapsed < 10, (code, elapsed, err, masks)
    assert interrupted_line(err) == f"interrupted: 0 of 4 runs kept in {out}; run the same command again to resume"
    assert "Traceback" not in err
    # 2. SIGTERM after the first finished run
    proc = start(out)
    wait_for(proc, "] 1/4 runs")
    code, err, elapsed, masks = interrupt(proc, signal.SIGTERM)
    assert code == 143 and elapsed < 10, (code, elapsed, err, masks)
    kept = int(interrupted_line(err).split()[1])
    assert 1 <= kept <= 4
    assert len(list((out / "parts").glob("*.run.parquet"))) == kept
    # 3. Ctrl-C once every run is done, while the results are gathered (or just after; with
    # every run kept in step 2 there is no progress line, only the summary)
    proc = start(out)
    wait_for(proc, "4/4 runs" if kept < 4 else "best gains")
    code, err, elapsed, masks = interrupt(proc, signal.SIGINT)
    assert code in (0, 130) and elapsed < 10, (code, elapsed, err, masks)
    if code == 130:
        assert interrupted_line(err).startswith("interrupted: 4 of 4 runs kept")
    # 4. the same command finishes from what was kept
    done = subprocess.run([sys.executable, "-m", "heurtune.experiment", *ARGS, "--out", str(out), "--no-figures"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "0 of 4 runs to do" in done.stdout or "runs to do" not in done.stdout
    assert (out / "runs.parquet").exists()


# SIGINT in `make test`, SIGTERM (the same handler, another exit code) in `make test-long`
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), pytest.param(signal.SIGTERM, 143, marks=pytest.mark.long)])
def test_interrupt_in_lockstep(tmp_path, sig, code):
    out = tmp_path / "r"
    proc = start(out, "--lockstep")
    wait_for(proc, "runs to do")
    time.sleep(1.0)  # inside the runs' first generations
    got, err, elapsed, masks = interrupt(proc, sig)
    assert got == code and elapsed < 10, (got, elapsed, err, masks)
    assert interrupted_line(err).startswith("interrupted: 0 of 4 runs kept")


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="needs pthread_sigmask")
# SIGINT in `make test`, SIGTERM (the same handler, another exit code) in `make test-long`
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), pytest.param(signal.SIGTERM, 143, marks=pytest.mark.long)])
def test_a_command_started_with_the_signals_blocked_still_stops(tmp_path, sig, code):
    """A block inherited from the parent is lifted at start-up: without that the signal waits,
    pending, and the experiment runs to its end with exit code 0. One worker: with a pool, the
    start of multiprocessing's resource tracker happens to unblock both signals as well."""
    proc = start(tmp_path / "r", "--jobs", "1", blocked=True)
    wait_for(proc, "runs to do")
    got, err, elapsed, masks = interrupt(proc, sig)
    assert got == code and elapsed < 10, (got, elapsed, err, masks)
    assert interrupted_line(err).startswith("interrupted: 0 of 4 runs kept")


def caught_signals(pid) -> int:
    """The mask of signals process ``pid`` has handlers for (Linux /proc)."""
    with open(f"/proc/{pid}/status") as fh:
        return int(next(line for line in fh if line.startswith("SigCgt:")).split()[1], 16)


def alive(pid) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not yet reaped, does not)."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            return next(line for line in fh if line.startswith("State:")).split()[1] != "Z"
    except (FileNotFoundError, StopIteration):
        return False


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs Linux /proc")
@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_during_the_imports_is_one_line(tmp_path, sig, code):
    """Sent as soon as the command's start-up handler is in place (it catches SIGTERM, which
    Python alone does not): at that moment the command is importing its modules, or, on a fast
    machine, already past them; either way one line and the exit code, no traceback."""
    proc = start(tmp_path / "r")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if caught_signals(proc.pid) & (1 << (signal.SIGTERM - 1)):
                break
        except (FileNotFoundError, StopIteration):
            pass
        time.sleep(0.001)
    got, err, _, masks = interrupt(proc, sig)
    assert got == code, (got, err, masks)
    assert len([line for line in err.splitlines() if line.startswith("interrupted")]) == 1, err
    assert "Traceback" not in err and "partially initialized" not in err


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="needs Linux /proc")
def test_workers_of_a_killed_parent_stop(tmp_path):
    """SIGKILL of the experiment (no handler runs): its workers notice that their parent is
    gone and exit (they check twice a second; allowed here: 30 s, for a loaded machine)."""
    cfg = tmp_path / "slow.toml"
    cfg.write_text('extends = "cs_folqi_qtp"\nruns = 4\n[[optimisers]]\nname = "cs"\nsettings = { n = 25 }\n'
                   'max_epochs = 400\n')
    proc = subprocess.Popen([sys.executable, "-m", "heurtune.experiment", str(cfg), "--out", str(tmp_path / "r"),
                             "--jobs", "2", "--no-figures"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        wait_for(proc, "runs to do")
        deadline = time.monotonic() + 120
        workers = []
        while time.monotonic() < deadline and len(workers) < 2:
            workers = [int(p) for p in subprocess.run(["pgrep", "-P", str(proc.pid)], capture_output=True,
                                                      text=True).stdout.split()]
            time.sleep(0.1)
        assert len(workers) >= 2, workers
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and any(alive(w) for w in workers):
            time.sleep(0.1)
        left = [open(f"/proc/{w}/cmdline").read().replace("\0", " ")[:200] for w in workers if alive(w)]
        assert not left, f"still running after their parent was killed: {left}"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="needs pthread_sigmask")
def test_the_start_up_guard_keeps_an_ignored_signal_ignored(monkeypatch):
    """A background job of a script (``cmd &``) starts with SIGINT ignored: the guard
    leaves it so (and restores it so), guards SIGTERM, and lifts an inherited block of both."""
    from heurtune import _startup

    monkeypatch.setattr(_startup, "_command", lambda: True)
    monkeypatch.setattr(_startup, "_GUARDED", [])
    saved = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        _startup.guard()
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) is _startup._stop
        assert not {signal.SIGINT, signal.SIGTERM} & signal.pthread_sigmask(signal.SIG_BLOCK, set())
        _startup.release()
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) == (signal.SIG_DFL if saved[1] is None else saved[1])
    finally:
        signal.signal(signal.SIGINT, saved[0])
        signal.signal(signal.SIGTERM, saved[1])
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def test_a_signal_raised_inside_a_c_call_counts_as_the_signal():
    """A handler that raises while a C function runs makes it return with an exception set, which
    Python turns into a SystemError caused by the signal's exception: that is still Ctrl-C or
    SIGTERM (exit 130 or 143), not a crash (it failed the SIGTERM test once in a few hundred)."""
    from heurtune.runner.experiment import Terminated, _signal_of

    def wrapped(signal_exc):
        try:
            raise signal_exc
        except BaseException as inner:
            try:
                raise SystemError("<built-in function x> returned a result with an exception set") from inner
            except SystemError as outer:
                return outer

    assert isinstance(_signal_of(wrapped(Terminated())), Terminated)
    assert isinstance(_signal_of(wrapped(KeyboardInterrupt())), KeyboardInterrupt)
    assert _signal_of(SystemError("unrelated")) is None and _signal_of(ValueError()) is None


@pytest.mark.long  # 30 s on the EPYC
# two workers: the suite's folders side by side; one: one after another, each stopped by its run_experiment
@pytest.mark.parametrize("jobs, sig, code", [("2", signal.SIGINT, 130), ("1", signal.SIGTERM, 143)])
def test_a_suite_interrupted_after_its_first_folder_resumes(tmp_path, jobs, sig, code):
    out = tmp_path / "suite"
    args = ["-m", "heurtune.suite", "--smoke", "--algorithms", "pso,cs", "--jobs", jobs, "--no-figures", "--no-ioh",
            "--out", str(out)]
    proc = subprocess.Popen([sys.executable, "-c", LAUNCH, "default", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    before = []
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not any(" / " in line for line in before):
        line = proc.stderr.readline()  # "suite: <problem> / <algorithm>: ..." once a folder is done
        if not line:
            break
        before.append(line)
    assert any(" / " in line for line in before), before
    got, err, elapsed, masks = interrupt(proc, sig)
    err = "".join(before) + err
    assert got == code and elapsed < 15, (got, elapsed, err, masks)
    assert "Traceback" not in err
    assert "run the same command again to resume" in interrupted_line(err)
    assert not list(out.rglob(".heurtune.lock")), "a folder is still locked"
    done = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    for problem in ("iolqi-min-limits", "pid-min"):
        for alg in ("pso", "cs"):
            assert len(pd.read_parquet(out / problem / alg / "runs.parquet")) == 4


def test_sigterm_raises_only_in_its_block_in_the_main_thread_and_keeps_an_ignored_signal_ignored():
    """Both commands' SIGTERM handler (``experiment.sigterm_raises``): inside the block SIGTERM
    raises ``Terminated``; after it the previous handler is back; a SIGTERM ignored at start stays
    ignored; and a thread, where Python sets no handler, leaves the handler as it was."""
    from heurtune.runner.experiment import Terminated, sigterm_raises

    saved = signal.getsignal(signal.SIGTERM)

    def previous(signum, frame):  # a caller's own handler, to see it restored
        pass

    try:
        signal.signal(signal.SIGTERM, previous)
        with pytest.raises(Terminated), sigterm_raises():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler runs between bytecodes, well before this ends
        assert signal.getsignal(signal.SIGTERM) is previous

        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        with sigterm_raises():
            assert signal.getsignal(signal.SIGTERM) == signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_IGN

        signal.signal(signal.SIGTERM, previous)
        seen = []

        def in_a_thread():
            with sigterm_raises():
                seen.append(signal.getsignal(signal.SIGTERM))

        worker = threading.Thread(target=in_a_thread)
        worker.start()
        worker.join()
        assert seen == [previous]
        assert signal.getsignal(signal.SIGTERM) is previous
    finally:
        signal.signal(signal.SIGTERM, saved)
