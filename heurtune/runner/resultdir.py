"""The results folder of an experiment: what made each part, which parts can be reused, one writer.

An experiment writes one ``parts/<run>.run.parquet`` (and ``.history.parquet``, and for some
drivers ``.starts.parquet`` and ``.pareto.parquet``) per finished run. Each part carries, in its
parquet metadata, the *fingerprint* of the run that made it (:func:`run_fingerprint`): the
problem's identity, the optimiser's name, resolved settings and budget (constraint and bound
handling included), the root seed and the run's seed key. A rerun reuses a part only when its
fingerprint is the one the current config plans for that name:

- a part whose file cannot be read, whose content names another run than its file name, or
  whose history is missing or damaged is *set aside* in
  ``parts/corrupt/`` with a one-line warning, and its run is computed again;
- a part made by another config is a :class:`~heurtune.core.errors.ConfigError` naming the keys
  that differ (the folder holds another experiment's runs: ``--fresh`` or another ``--out``),
  and so is a part of an earlier heurtune, which carries no fingerprint.

:class:`FolderLock` lets one process write into a folder at a time.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import socket
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq

from heurtune.core.errors import ConfigError

__all__ = [
    "run_fingerprint",
    "fingerprint_of",
    "fingerprint_digest",
    "matching_parts",
    "differing_keys",
    "read_part",
    "part_origin",
    "PartCheck",
    "check_parts",
    "set_aside",
    "set_aside_file",
    "clear_folder",
    "FolderLock",
    "METADATA_KEY",
    "ORIGIN_KEY",
    "LOCK_FILE",
    "CORRUPT_DIR",
]

# The parquet metadata key of a part's fingerprint.
METADATA_KEY = b"heurtune.fingerprint"
# The parquet metadata key of what made a run part: the git commit and dirty flag of the process
# that ran it (not part of the fingerprint: the same run made by another commit is reusable).
ORIGIN_KEY = b"heurtune.origin"
LOCK_FILE = ".heurtune.lock"
CORRUPT_DIR = "corrupt"
# The columns of a run part that must match its file name.
_IDENTITY_COLUMNS = ("case", "algorithm", "optimiser_index", "run", "seed_key")


def run_fingerprint(spec, problem_identity: dict) -> dict:
    """What made a run (a JSON-able dict): everything its result depends on.

    Parameters
    ----------
    spec : RunSpec
        The planned run.
    problem_identity : dict
        ``prob.identity()`` of its case (a baseline run's too: its fixed gains are evaluated on
        that problem).

    Returns
    -------
    dict
    """
    return dict(problem=_jsonable(problem_identity), algorithm=spec.algorithm, optimiser_index=spec.optimiser_index,
                settings=_jsonable(spec.settings), budget=_jsonable(spec.budget), seed=int(spec.root_seed),
                seed_key=spec.seed_key, baseline=bool(spec.baseline))


def _jsonable(value):
    """``value`` as plain JSON types (tuples as lists, numpy scalars as numbers), so that a
    fingerprint read back from a file compares equal to a freshly computed one."""
    return json.loads(json.dumps(value, sort_keys=True, default=_default))


def _default(value):
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (set, frozenset, tuple)):
        return list(value)
    return str(value)


def fingerprint_of(path) -> dict | None:
    """The fingerprint stored in a part's metadata; None without one. Raises on a damaged file.

    Parameters
    ----------
    path : str or Path
        A part file.

    Returns
    -------
    dict or None
    """
    meta = pq.read_schema(path).metadata or {}
    text = meta.get(METADATA_KEY)
    return None if text is None else json.loads(text)


def fingerprint_digest(fingerprint: dict) -> str:
    """A short hash of a run's fingerprint (``planned.json`` keeps these for ``--status``).

    Parameters
    ----------
    fingerprint : dict

    Returns
    -------
    str
    """
    return hashlib.sha256(json.dumps(fingerprint, sort_keys=True).encode()).hexdigest()[:16]


def matching_parts(parts: Path, names, digests: dict | None) -> set:
    """The runs among ``names`` whose run part reads and, where ``digests`` says what the plan
    expects (:func:`fingerprint_digest` by run), carries that fingerprint.

    Parameters
    ----------
    parts : Path
        The results folder's ``parts/``.
    names : iterable of str
        Run names.
    digests : dict of str to str, or None
        The expected digest of each run; None accepts any readable part.

    Returns
    -------
    set of str
    """
    out = set()
    for name in names:
        path = Path(parts) / f"{name}.run.parquet"
        if not path.exists():
            continue
        try:
            found = fingerprint_of(path)
        except Exception:  # damaged: not counted (the next run sets it aside)
            continue
        if digests is None or (found is not None and fingerprint_digest(found) == digests.get(name)):
            out.add(name)
    return out


def differing_keys(found: dict, expected: dict, prefix: str = "") -> list:
    """Dotted names of the keys whose values differ between two fingerprints (nested dicts
    compared key by key: ``problem.bounds.Q11``, ``settings.pa``, ``budget.max_epochs``).

    Parameters
    ----------
    found, expected : dict
        Two fingerprints.
    prefix : str
        The dotted path of these dicts (for the recursion).

    Returns
    -------
    list of str
    """
    keys = []
    for key in sorted(set(found) | set(expected)):
        a, b = found.get(key, "<absent>"), expected.get(key, "<absent>")
        if isinstance(a, dict) and isinstance(b, dict):
            keys += differing_keys(a, b, f"{prefix}{key}.")
        elif a != b:
            keys.append(f"{prefix}{key}")
    return keys


def _load_part(path, cache):
    """``(DataFrame, schema metadata)`` of a part file, from ``cache`` while the file is the one
    read before (the same inode, size and modification time)."""
    key = None
    if cache is not None:
        try:
            st = os.stat(path)
            key = (st.st_ino, st.st_size, st.st_mtime_ns)
        except OSError:  # missing: read_table says so below
            pass
        hit = cache.get(str(path))
        if key is not None and hit is not None and hit[0] == key:
            return hit[1], hit[2]
    try:
        table = pq.read_table(path)
    except Exception as exc:  # truncated, empty, not parquet: pyarrow raises several types
        raise ValueError(f"unreadable ({type(exc).__name__})") from None
    meta = dict(table.schema.metadata or {})
    df = table.to_pandas()
    if key is not None:
        cache[str(path)] = (key, df, meta)
    return df, meta


def read_part(path, spec=None, *, cache=None):
    """A part's table and fingerprint: ``(DataFrame, dict or None)``. Raises ``ValueError``
    with the reason when the file is damaged or (``spec`` given, a run part) its content names
    another run than its file name.

    Parameters
    ----------
    path : str or Path
        A part file.
    spec : RunSpec, optional
        The run the part should hold.
    cache : dict, optional
        Tables already read in this command (:func:`check_parts` fills it, the gathering of the
        results reads from it): a file is read once while it is unchanged, and read again when
        its inode, size or modification time differ. The tables it returns are shared: do not
        modify them.

    Returns
    -------
    tuple
        ``(DataFrame, dict or None)``.
    """
    df, meta = _load_part(path, cache)
    text = meta.get(METADATA_KEY)
    if spec is not None:
        if len(df) != 1:
            raise ValueError(f"{len(df)} rows where a run part has 1")
        missing = [c for c in _IDENTITY_COLUMNS if c not in df.columns]
        if missing:
            raise ValueError(f"no {', '.join(missing)} column")
        row = df.iloc[0]
        expected = dict(case=spec.case, algorithm=spec.algorithm, optimiser_index=spec.optimiser_index,
                        run=spec.run, seed_key=spec.seed_key)
        wrong = [c for c in _IDENTITY_COLUMNS if str(row[c]) != str(expected[c])]
        if wrong:
            raise ValueError("holds another run (" + ", ".join(f"{c} = {row[c]!r}" for c in wrong) + ")")
    try:
        fingerprint = None if text is None else json.loads(text)
    except ValueError:
        raise ValueError("its fingerprint is not JSON") from None
    return df, fingerprint


def part_origin(path, *, cache=None) -> dict | None:
    """What made a run part: ``{"git_commit": str, "git_dirty": bool or None, "written": str}`` as
    the process that ran it recorded them (:data:`ORIGIN_KEY`; ``written`` the local time of the
    writing, ISO 8601 with its UTC offset, absent from parts written before heurtune recorded it),
    or None for a part written before heurtune recorded its origin. Raises ``ValueError`` as
    :func:`read_part` does.

    Parameters
    ----------
    path : str or Path
        A part file.
    cache : dict, optional
        As for :func:`read_part`.

    Returns
    -------
    dict or None
    """
    _, meta = _load_part(path, cache)
    text = meta.get(ORIGIN_KEY)
    try:
        return None if text is None else json.loads(text)
    except ValueError:
        raise ValueError("its origin is not JSON") from None


class ResultsOfAnotherConfig(ConfigError):
    """A results folder holds runs that another config made (:meth:`PartCheck.refuse_mismatch`).

    Attributes
    ----------
    out_dir : Path
    runs : int
        How many of its runs differ.
    differing : str
        The differing config keys, as the message names them.
    """

    def __init__(self, out_dir, runs: int, differing: str):
        self.out_dir, self.runs, self.differing = Path(out_dir), runs, differing
        super().__init__(f"{out_dir} holds {runs} run(s) of a different config (differing: {differing}); "
                         "use --fresh to discard them or another --out")


class PartCheck:
    """What :func:`check_parts` found: the reusable run names, the set-aside ones, and the
    mismatches (run name to differing keys)."""

    def __init__(self):
        self.reusable: set = set()
        self.set_aside: dict = {}
        self.mismatched: dict = {}
        self.legacy: set = set()

    def refuse_mismatch(self, out_dir) -> None:
        """Raise the one-line ConfigError for parts of another config, or of an earlier
        heurtune that wrote no fingerprints, if any."""
        if self.legacy:
            raise ConfigError(f"{out_dir} was written by an earlier heurtune ({len(self.legacy)} run part(s) without a "
                              "fingerprint, so what made them cannot be checked); use --fresh to redo them or "
                              "another --out")
        if not self.mismatched:
            return
        keys = sorted({k for ks in self.mismatched.values() for k in ks})
        shown = ", ".join(keys[:6]) + (f" and {len(keys) - 6} more" if len(keys) > 6 else "")
        raise ResultsOfAnotherConfig(out_dir, len(self.mismatched), shown)


def check_parts(parts: Path, specs, fingerprints: dict, *, dry=False, cache=None) -> PartCheck:
    """Check the finished parts of the planned runs ``specs`` against ``fingerprints`` (run name
    to the fingerprint the current config gives it).

    A run part is reusable when it is readable, names its own run, carries the expected
    fingerprint, and its history part does too. Damaged or misnamed parts are moved to
    ``parts/corrupt/`` with a warning on stderr (``dry``: only reported in ``set_aside``); parts of
    another config are reported in
    ``mismatched`` and parts of an earlier heurtune, which carry no fingerprint, in ``legacy``,
    neither moved.

    Parameters
    ----------
    parts : Path
        The results folder's ``parts/``.
    specs : iterable of RunSpec
        The planned runs.
    fingerprints : dict of str to dict
        The fingerprint the current config gives each run.
    dry : bool
        Only report; move nothing.
    cache : dict, optional
        Filled with the tables read, for the later reads of the same command (:func:`read_part`).

    Returns
    -------
    PartCheck
    """
    check = PartCheck()
    parts = Path(parts)
    for spec in specs:
        name = spec.part_name
        run_file = parts / f"{name}.run.parquet"
        if not run_file.exists():
            continue
        expected = fingerprints[name]
        try:
            _, found = read_part(run_file, spec, cache=cache)
            if found is None:
                check.legacy.add(name)
                continue
            keys = differing_keys(found, expected)
            if keys:
                check.mismatched[name] = keys
                continue
            hist = parts / f"{name}.history.parquet"
            if not hist.exists():
                raise ValueError("its history part is missing")
            try:
                _, hist_found = read_part(hist, cache=cache)
            except ValueError as exc:
                raise ValueError(f"its history part is {exc}") from None
            if hist_found != found:
                raise ValueError("its history part was made by another run")
        except ValueError as exc:
            check.set_aside[name] = str(exc)
            if not dry:
                set_aside(parts, name, str(exc))
            continue
        check.reusable.add(name)
    return check


def set_aside(parts: Path, name: str, reason: str) -> None:
    """Move every file of run ``name`` from ``parts`` to ``parts/corrupt/``, with a one-line warning.

    Parameters
    ----------
    parts : Path
    name : str
        The run.
    reason : str
        Why, for the warning.
    """
    for path in sorted(Path(parts).glob(f"{name}.*")):
        if path.is_file():
            _move_aside(path)
    print(f"warning: {Path(parts) / name}.run.parquet: {reason}; set aside in {Path(parts) / CORRUPT_DIR}, "
          "the run is computed again", file=sys.stderr)


def set_aside_file(path, reason: str) -> None:
    """Move one damaged part (a multistart's saved solves) to ``corrupt/`` beside it, with a warning.

    Parameters
    ----------
    path : str or Path
    reason : str
        Why, for the warning.
    """
    dest = _move_aside(Path(path))
    print(f"warning: {path}: {reason}; set aside as {dest}, its work is done again", file=sys.stderr)


def _move_aside(path: Path) -> Path:
    target = path.parent / CORRUPT_DIR
    target.mkdir(exist_ok=True)
    dest, k = target / path.name, 1
    while dest.exists():  # numbered when a file of that name was set aside before
        dest, k = target / f"{path.name}.{k}", k + 1
    os.replace(path, dest)
    return dest


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        return True
    return True


class FolderLock:
    """One writer per results folder: ``DIR/.heurtune.lock``, created atomically, holds the
    writer's pid, host and start time.

    A second writer refuses with a ConfigError naming the holder. A lock left by a process that
    no longer runs on this host is taken over with a warning; one held from another host is
    refused (its process cannot be checked from here): remove the file when that run is known
    to be gone.
    """

    def __init__(self, folder):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_FILE
        self.held = False

    def _record(self) -> str:
        return json.dumps(dict(pid=os.getpid(), host=socket.gethostname(), since=time.strftime("%Y-%m-%dT%H:%M:%S%z")))

    def acquire(self) -> None:
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is None:  # being written, or damaged: look again
                    time.sleep(0.05)
                    holder = self._holder()
                if holder is not None and not self._stale(holder):
                    raise ConfigError(f"{self.folder} is being written by pid {holder.get('pid')} on "
                                      f"{holder.get('host')} (since {holder.get('since')}); wait for it, or "
                                      "use another --out") from None
                who = "an unreadable lock" if holder is None else f"pid {holder.get('pid')}, which no longer runs"
                print(f"warning: {self.path}: taking over {who}", file=sys.stderr)
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.path)
                continue
            with os.fdopen(fd, "w") as fh:
                fh.write(self._record())
            self.held = True
            return
        raise ConfigError(f"{self.path}: could not take the lock (another process keeps taking it)")

    def _holder(self) -> dict | None:
        try:
            holder = json.loads(self.path.read_text())
        except (OSError, ValueError):
            return None
        return holder if isinstance(holder, dict) else None

    @staticmethod
    def _stale(holder: dict) -> bool:
        if holder.get("host") != socket.gethostname():
            return False
        try:
            pid = int(holder.get("pid"))
        except (TypeError, ValueError):
            return True
        return pid != os.getpid() and not _pid_alive(pid)

    def release(self) -> None:
        if self.held:
            holder = self._holder()
            if holder is not None and holder.get("pid") == os.getpid():
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self.path)
            self.held = False

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()
        return False


def clear_folder(folder: Path, keep=(LOCK_FILE,)) -> None:
    """Remove everything in ``folder`` except the names in ``keep`` (``--fresh`` under the lock).

    Parameters
    ----------
    folder : Path
    keep : iterable of str
        Names left in place.
    """
    for path in Path(folder).iterdir():
        if path.name in keep:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
