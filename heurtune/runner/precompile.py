"""Fill numba's on-disk cache with the kernels the shipped experiments run.

``python -m heurtune.precompile`` (this module's :func:`main`) evaluates a few random
candidates of every case of every shipped experiment on each CPU device (``cpu``,
``cpu-batch``), and of the QTP experiments also with the sampled loop (``[controller]
sample_time``) and under all their scenarios at once; a TITO problem, which simulates only the
candidates its frequency check passes, also simulates one, ``ga_pi_ccts`` (on the
continuous loop to its tolerance) runs on that loop's fixed step too, and ``cs_folqi_qtp`` with
the linearised integrator; the margins that a results folder reports are computed for one
candidate of each case. Every kernel those evaluations call
is compiled and written to numba's cache (``__pycache__`` beside the sources, or
``NUMBA_CACHE_DIR``), so a later run, test or worker process loads it instead of compiling.
``make setup`` and ``make test`` call it; with a filled cache it takes seconds.

A full run leaves a stamp in the cache (``heurtune-precompile.json``): the numba version, the
CPU numba compiles for, the size and modification time of every source and config file of the
package, and of every index file of the cache. While none of them has changed, a later call
(without names or ``--force``) says so and stops in well under a second; an edited kernel, a
new experiment, another numba or CPU, or a removed cache runs it again.

The work is split over ``--jobs`` processes (default: the number of CPUs, at most 2) so that
no two processes compile the same kernel: the QTP experiments' one-candidate kernels in one,
their batched kernels and the other families' kernels in the other (about equal shares). The
cache is for this CPU: numba compiles for the host's instruction set and keys its cache by it,
so another machine (or ``NUMBA_CPU_NAME``) compiles anew.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import io
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

# QTP experiments whose sampled loop (sample_time = 0.01) is compiled too: one with a single
# scenario and one with several (the robust one), which call different kernels.
SAMPLED = ("cs_lqi_qtp", "robust_cs_folqi_qtp")
# A TITO experiment run on the continuous loop's fixed step too ([scenario] loop = "continuous"
# with dt; the experiment itself runs it to a tolerance).
CONTINUOUS = ("ga_pi_ccts",)
# A QTP experiment run with the linearised integrator too ([scenario] integrator = "linearised";
# one candidate at a time on every device, so on the CPU alone).
LINEARISED = ("cs_folqi_qtp",)
_VARIANTS = {"sampled": "[controller]\nsample_time = 0.01\n",
             "continuous": '[scenario]\nloop = "continuous"\ndt = 0.5\n',
             "linearised": '[scenario]\nintegrator = "linearised"\n'}


DEVICES = ("cpu", "cpu-batch")


def _warm_problem(prob, rng, devices=DEVICES) -> None:
    import numpy as np

    lo, hi = np.asarray(prob.lower, float), np.asarray(prob.upper, float)
    X = lo + (hi - lo) * rng.random((3, prob.dim))
    for device in devices:
        try:
            prob.set_device(device)
        except Exception:  # a family without that device
            continue
        prob.evaluate(X)
        prob.evaluate(X[:1])
        scenarios = list(getattr(prob, "scenarios", None) or [])
        if len(scenarios) > 1:
            prob.evaluate_scenarios(X, scenarios)
    with contextlib.suppress(Exception):
        prob.set_device("cpu")
    # a family that simulates only candidates its frequency check passes (TITO): one simulation
    if hasattr(prob, "simulated_metrics"):
        with contextlib.suppress(Exception):
            prob.simulated_metrics(X[0])
    # the margins of the best runs that a folder's gathering reports (QTP: a compiled response),
    # with the one-candidate kernels (one process compiles each kernel)
    if hasattr(prob, "margins") and "cpu" in devices:
        with contextlib.suppress(Exception):
            prob.margins(X[0])


def warm(names: list[str]) -> list[str]:
    """Evaluate candidates of each named experiment (see the module docstring).

    Parameters
    ----------
    names : list of str
        Shipped experiment names; ``"NAME:sampled"`` for a QTP experiment's sampled loop,
        ``"NAME:linearised"`` for its linearised integrator, ``"NAME:continuous"`` for a TITO
        experiment's continuous loop;
        ``"NAME@DEVICE"`` (``cpu`` or ``cpu-batch``) for one device only (default: both).

    Returns
    -------
    list of str
        One line per experiment: its name and seconds taken, or the error it raised.
    """
    import numpy as np

    from heurtune.runner.config import load_experiment

    lines = []
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory(prefix="heurtune-precompile-") as tmp:
        for name in names:
            start = time.perf_counter()
            name, _, device = name.partition("@")
            try:
                with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()), \
                        contextlib.redirect_stderr(io.StringIO()):
                    warnings.simplefilter("ignore")
                    devices = (device,) if device else DEVICES
                    base, _, variant = name.partition(":")
                    if variant:
                        cfg = Path(tmp) / f"{base}_{variant}.toml"
                        cfg.write_text(f'extends = "{base}"\n{_VARIANTS[variant]}')
                        experiment = load_experiment(str(cfg))
                    else:
                        experiment = load_experiment(name)
                    for case in experiment.cases:
                        _warm_problem(experiment.problem(case), rng, devices)
                lines.append(f"{name}{'@' + device if device else ''}: {time.perf_counter() - start:.1f} s")
            except Exception as exc:  # a broken experiment is the tests' business, not set-up's
                lines.append(f"{name}: not compiled ({type(exc).__name__}: {str(exc)[:120]})")
    return lines


def _groups(jobs: int) -> list[list[str]]:
    """The shipped experiments in ``jobs`` groups, one family's kernels in one group."""
    from heurtune.runner.config import list_experiments, load_config

    by_family: dict[str, list[str]] = {}
    for name in list_experiments():
        try:
            model = load_config(name).get("plant", {}).get("model", "qtp")
        except Exception:
            model = "?"
        family = "qtp" if str(model).startswith("qtp") else str(model)
        by_family.setdefault(family, []).append(name)
    qtp = by_family.pop("qtp", []) + [f"{name}:sampled" for name in SAMPLED]
    rest = [name for family in sorted(by_family) for name in by_family[family]]
    rest += [f"{name}:continuous" for name in CONTINUOUS]
    rest += [f"{name}:linearised@cpu" for name in LINEARISED]
    if jobs <= 1:
        return [qtp + rest]
    return [[f"{name}@cpu" for name in qtp], [f"{name}@cpu-batch" for name in qtp] + rest]


STAMP = "heurtune-precompile.json"
# The package's folders (heurtune.algorithms, .objectives and .experiments live beside heurtune/).
_SOURCES = ("heurtune", "algorithms", "objectives", "experiments")


def _cache_dirs() -> tuple[Path, list[Path]]:
    """Where the stamp goes, and the folders numba's index files are in."""
    root = Path(__file__).resolve().parents[2]
    custom = os.environ.get("NUMBA_CACHE_DIR")
    if custom:
        return Path(custom), [Path(custom)]
    return root / "heurtune" / "__pycache__", [root / name for name in _SOURCES]


def _stat(path: Path) -> list[int]:
    st = path.stat()
    return [st.st_size, st.st_mtime_ns]


def _state() -> dict:
    """What a full run's result depends on (the module docstring): numba, the CPU, the files."""
    import numba
    from llvmlite import binding

    root = Path(__file__).resolve().parents[2]
    sources = {str(path.relative_to(root)): _stat(path) for name in _SOURCES
               for path in sorted((root / name).rglob("*")) if path.suffix in (".py", ".toml")}
    _, folders = _cache_dirs()
    index = {str(path): _stat(path) for folder in folders if folder.is_dir() for path in sorted(folder.rglob("*.nbi"))}
    cpu = os.environ.get("NUMBA_CPU_NAME") or binding.get_host_cpu_name()
    return {"numba": numba.__version__, "python": sys.version, "cpu": cpu,
            "features": os.environ.get("NUMBA_CPU_FEATURES", ""), "sources": sources, "index": index}


def _up_to_date() -> bool:
    """Whether the stamp of the last full run still holds: the same numba, CPU and sources, and
    every index file it saw unchanged (index files written since, by kernels compiled outside
    the shipped experiments, do not matter)."""
    stamp_dir, _ = _cache_dirs()
    try:
        old = json.loads((stamp_dir / STAMP).read_text())
        now = _state()
    except (OSError, ValueError):
        return False
    same = all(old.get(key) == now[key] for key in ("numba", "python", "cpu", "features", "sources"))
    index = old.get("index")
    return same and isinstance(index, dict) and bool(index) and all(now["index"].get(k) == v for k, v in index.items())


def _write_stamp() -> None:
    stamp_dir, _ = _cache_dirs()
    with contextlib.suppress(OSError):  # a read-only install: no stamp, the next call runs again
        stamp_dir.mkdir(parents=True, exist_ok=True)
        tmp = stamp_dir / f".{STAMP}.{os.getpid()}"
        tmp.write_text(json.dumps(_state()))
        os.replace(tmp, stamp_dir / STAMP)


def main(argv=None) -> None:
    """Command line of ``python -m heurtune.precompile``.

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: ``sys.argv[1:]``).
    """
    ap = argparse.ArgumentParser(
        prog="python -m heurtune.precompile",
        description="Fill numba's cache with the kernels of the shipped experiments.",
        epilog="example: python -m heurtune.precompile --jobs 2")
    ap.add_argument("names", nargs="*", help="experiments to warm (default: every shipped one)")
    ap.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                    help="processes (default: the CPUs, at most 2)")
    ap.add_argument("--quiet", action="store_true", help="print only the total")
    ap.add_argument("--force", action="store_true",
                    help="run even when the stamp says nothing changed since the last full run")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs = {args.jobs}: give 1 or more")
    start = time.perf_counter()
    if not args.names and not args.force and _up_to_date():
        print("precompile: numba's cache is up to date (nothing changed since the last full run; --force runs it)",
              file=sys.stderr)
        return
    groups = [args.names] if args.names else _groups(args.jobs)
    if len(groups) == 1:
        lines = warm(groups[0])
    else:
        with concurrent.futures.ProcessPoolExecutor(len(groups)) as pool:
            lines = [line for result in pool.map(warm, groups) for line in result]
    if not args.quiet:
        print("\n".join(lines))
    failed = [line for line in lines if "not compiled" in line]
    if not args.names and not failed:
        _write_stamp()
    print(f"precompile: {len(lines) - len(failed)} experiments' kernels in numba's cache "
          f"({time.perf_counter() - start:.0f} s){'; ' + str(len(failed)) + ' not compiled' if failed else ''}",
          file=sys.stderr)


if __name__ == "__main__":
    main()
