"""A kernel freshly compiled and the same kernel loaded from numba's cache give the same numbers.

A first run from a fresh clone compiles the kernels; every later run (and every worker of a
run) loads them from numba's on-disk cache. A jitted function that its caller does not inline is
compiled twice: on its own, and as a copy inside the caller's object code. The fresh process
calls the first, a process that loads the caller from the cache the second. Under a fast-math
licence that lets LLVM reassociate, the two copies were optimised differently, and the TV and
umax of LQI candidates parted at 3e-15 relative between a first run and later ones; an
optimiser's path can follow such a difference. The test compiles the QTP kernels into an empty
cache in one process, loads them in a second, and asks for the same bits: on the continuous loop
(one candidate, lanes and robust scenarios) and on the sampled loop (one candidate and
scenarios).

The two subprocesses take about a minute (most of it the first one's compilation).
"""

import json
import os
import subprocess
import sys
import textwrap

import pytest

# a fresh compilation of every QTP kernel: `make test-long` (docs/testing.md, "Two tiers")
pytestmark = pytest.mark.long

_SCRIPT = textwrap.dedent(
    """
    import json, sys, warnings
    import numpy as np
    warnings.simplefilter("ignore")
    import heurtune

    sampled, robust_sampled = sys.argv[1:3]
    out = {}
    # the robust problem first: its scenarios kernel holds a copy of the one-scenario kernel, and
    # a process that loads the scenarios kernel before the other one runs that copy
    for name, case in ((robust_sampled, "min"), ("robust_cs_folqi_qtp", "min"), ("cs_lqi_qtp", "nmp"),
                       ("cs_lqi_qtp", "min"), ("cs_iolqi_qtp", "min"), ("cs_folqi_qtp", "min"),
                       (sampled, "nmp")):
        prob = heurtune.load_experiment(name).problem(case)
        lo, hi = np.asarray(prob.lower, float), np.asarray(prob.upper, float)
        X = lo + (hi - lo) * np.random.default_rng(5).random((40, prob.dim))
        for device in ("cpu", "cpu-batch"):
            prob.set_device(device)
            metrics = np.asarray(prob.evaluate(X).metrics, float)
            out[f"{name}:{case}:{device}"] = [v.hex() for v in metrics.ravel()]
    print(json.dumps(out))
    """
)


def _run(cache_dir, configs):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    done = subprocess.run([sys.executable, "-c", _SCRIPT, *map(str, configs)], env=env, capture_output=True,
                          text=True, timeout=1800)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_fresh_compilation_and_cached_kernels_agree_bit_for_bit(tmp_path):
    configs = []
    for name in ("cs_lqi_qtp", "robust_cs_folqi_qtp"):
        configs.append(tmp_path / f"sampled_{name}.toml")
        configs[-1].write_text(f'extends = "{name}"\n[controller]\nsample_time = 0.01\n')
    cache = tmp_path / "numba_cache"
    fresh = _run(cache, configs)
    assert any(cache.rglob("*.nbi")), "the first process wrote no numba cache"
    cached = _run(cache, configs)
    assert fresh.keys() == cached.keys()
    differ = [key for key in fresh if fresh[key] != cached[key]]
    assert not differ, f"fresh and cached kernels differ on {differ}"
