"""Generated documentation stays current."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_optimiser_reference_page_is_current():
    # In a fresh interpreter: tests register toy plugins that must not appear on the page.
    out = subprocess.run([sys.executable, "-m", "heurtune.algorithms", "--markdown"], check=True,
                         capture_output=True, text=True).stdout
    page = (ROOT / "docs" / "optimisers_reference.md").read_text()
    assert out == page, "regenerate with: python -m heurtune.algorithms --markdown > docs/optimisers_reference.md"


def test_listing_names_every_optimiser():
    out = subprocess.run([sys.executable, "-m", "heurtune.algorithms"], check=True, capture_output=True,
                         text=True).stdout
    for name in ("cs", "apso", "firefly", "pso", "ga", "sqp_multistart", "steepest_descent", "dfp", "bfgs",
                 "newton_raphson"):
        assert f"{name}: " in out


def test_listing_has_usage_and_takes_names():
    from heurtune.algorithms.__main__ import main

    def run(*argv):
        return subprocess.run([sys.executable, "-m", "heurtune.algorithms", *argv], capture_output=True, text=True)

    usage = run("--help")
    assert usage.returncode == 0 and usage.stdout.startswith("usage: python -m heurtune.algorithms")
    one = run("cs")
    assert one.returncode == 0 and one.stdout.startswith("cs: ") and "apso: " not in one.stdout
    assert main(["no_such_optimiser"]) == 2


def test_guide_plugin_runs_and_meets_the_contract(tmp_path):
    """The one-file optimiser of docs/optimisers.md works as printed."""
    from numerics import assert_same_bits

    import heurtune
    from heurtune.core.plugins import load_plugin

    text = (ROOT / "docs" / "optimisers.md").read_text()
    start = text.index('```python\n"""Greedy random walk') + len("```python\n")
    code = text[start:text.index("```", start)]
    path = tmp_path / "random_walk.py"
    path.write_text(code)
    load_plugin(str(path))
    lo, hi = [-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]
    a = heurtune.minimize(lambda X: ((X - 0.5) ** 2).sum(axis=1), lo, hi, "random_walk", max_evals=2000, seed=1)
    b = heurtune.minimize(lambda X: ((X - 0.5) ** 2).sum(axis=1), lo, hi, "random_walk", max_evals=2000, seed=1)
    assert a.n_evals == 2000 and a.f < 1e-2
    assert_same_bits(a.x, b.x, because="same seed")


def _python_blocks(text: str) -> list[str]:
    blocks, inside, lines = [], False, []
    for line in text.splitlines():
        if line.strip().startswith("```"):
            if inside:
                blocks.append("\n".join(lines))
                lines = []
            inside = not inside and line.strip() in ("```python", "```py")
            continue
        if inside:
            lines.append(line)
    return blocks


def test_every_import_in_the_docs_python_examples_works():
    """The ``import`` lines of every python block of README.md and docs/*.md run, and every
    ``module.name(`` the block calls on an imported heurtune module exists (docs/anytime.md once
    imported a module that does not hold the functions it then called)."""
    import importlib
    import re

    failures = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for block in _python_blocks(page.read_text()):
            modules = {}
            for stmt in re.findall(r"^(?:from heurtune[\w.]* import [\w, ]+|import heurtune[\w.]*(?: as \w+)?)\s*$",
                                   block, flags=re.M):
                namespace = {}
                try:
                    exec(stmt, namespace)
                except Exception as exc:  # noqa: BLE001 - reported below
                    failures.append(f"{page.name}: {stmt}: {type(exc).__name__}: {exc}")
                    continue
                modules.update({k: v for k, v in namespace.items() if getattr(v, "__name__", "").startswith("heurtune")
                                and type(v).__name__ == "module"})
            for alias, attr in re.findall(r"\b(\w+)\.(\w+)\(", block):
                if alias in modules and not hasattr(modules[alias], attr):
                    failures.append(f"{page.name}: {alias}.{attr} does not exist in {modules[alias].__name__}")
            importlib.invalidate_caches()
    assert not failures, "\n".join(failures)


def test_the_readmes_python_control_example_runs():
    """README's python-control block runs as written and gives the numbers its comments state."""
    text = (ROOT / "README.md").read_text()
    block = next(b for b in _python_blocks(text) if "linear_systems" in b)
    namespace = {}
    exec(block, namespace)
    assert abs(namespace["pm"] - 20.3) < 0.05 and abs(namespace["w_gc"] - 1.02) < 0.005
    assert namespace["y1"][0] == 1.0 and 0.0 < namespace["y1"][-1] < 1e-3
    assert namespace["cl"].input_labels == ["d1", "d2"]
    assert namespace["cl"].output_labels == ["y1", "y2", "du1", "du2"]


def test_objectives_guide_weighted_example_is_the_sum_it_states(tmp_path):
    """docs/objectives.md's weighted config, as printed, gives IAE1 + IAE2 + 0.05 (TV1 + TV2)."""
    import re

    import heurtune

    text = (ROOT / "docs" / "objectives.md").read_text()
    block = re.search(r"```toml\n(.*?)```", text, re.S).group(1)
    config = tmp_path / "weighted.toml"
    config.write_text(block)
    prob = heurtune.load_experiment(str(config)).problem("min")
    ev = prob.evaluate((prob.lower + prob.upper) / 2)
    m = dict(zip(ev.metric_names, ev.metrics[0]))
    assert ev.f[0] == pytest.approx(m["IAE1"] + m["IAE2"] + 0.05 * (m["TV1"] + m["TV2"]), rel=1e-12)
    from heurtune.objectives.qtp.problem import OBJECTIVES

    for name in OBJECTIVES:  # the table names every QTP objective
        assert f"`{name}`" in text


def test_each_extension_guide_fits_one_page():
    """The guides to a new optimiser, controller structure, plant family and objective are one
    page each: at most 80 lines (an A4 page of 10 pt text); their details live in the
    reference pages they link to."""
    for name in ("optimisers", "controllers", "plants", "objectives"):
        lines = (ROOT / "docs" / f"{name}.md").read_text().splitlines()
        assert len(lines) <= 80, (name, len(lines))


def test_optimiser_guide_config_runs_the_plugin(tmp_path):
    """docs/optimisers.md's config, beside the guide's plugin, loads as printed."""
    import re

    import heurtune

    text = (ROOT / "docs" / "optimisers.md").read_text()
    start = text.index('```python\n"""Greedy random walk') + len("```python\n")
    (tmp_path / "random_walk.py").write_text(text[start:text.index("```", start)].replace(
        '"random_walk"', '"guide_walk_cfg"'))
    toml = re.search(r"```toml\n(.*?)```", text, re.S).group(1).replace('"random_walk"', '"guide_walk_cfg"')
    (tmp_path / "my.toml").write_text(toml)
    exp = heurtune.load_experiment(str(tmp_path / "my.toml"))
    assert [o["name"] for o in exp.optimisers] == ["cs", "guide_walk_cfg"]


def test_objectives_guide_new_named_objective_runs_to_its_label(tmp_path, monkeypatch):
    """docs/objectives.md, step 5: a name added to OBJECTIVES (and to the schema that reads it
    at import) is tuned, summed and labelled, without a unit or a label of its own."""
    import heurtune
    from heurtune.objectives.qtp import family, problem

    monkeypatch.setitem(problem.OBJECTIVES, "iae_tv", ("IAE1", "IAE2", "TV1", "TV2"))
    monkeypatch.setitem(family.SCHEMA["problem"], "objective", tuple(problem.OBJECTIVES) + ("weighted",))
    config = tmp_path / "iae_tv.toml"
    config.write_text('extends = "benchmark_qtp"\n[problem]\nobjective = "iae_tv"\n')
    prob = heurtune.load_experiment(str(config)).problem("min")
    ev = prob.evaluate((prob.lower + prob.upper) / 2)
    m = dict(zip(ev.metric_names, ev.metrics[0]))
    assert ev.f[0] == pytest.approx(m["IAE1"] + m["IAE2"] + m["TV1"] + m["TV2"], rel=1e-12)
    assert prob.objective_label == "iae_tv"


def test_model_page_gives_every_preset_as_the_code_has_it():
    """docs/model.md's preset table: the parameters and the exact equilibrium of each QTP preset."""
    from heurtune.objectives.qtp.model import PRESETS, operating_point

    page = (ROOT / "docs" / "model.md").read_text()
    for name, p in PRESETS.items():
        row = next(line for line in page.splitlines() if line.startswith(f"| `{name}` |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        numbers = lambda cell: [float(v) for v in cell.replace(" each", "").split(",")]  # noqa: E731
        A = numbers(cells[1])
        assert (A * 4 if len(A) == 1 else A) == list(p.A), name
        assert numbers(cells[2]) == list(p.a) and numbers(cells[3]) == list(p.k), name
        assert numbers(cells[4]) == list(p.gamma) and numbers(cells[5]) == list(p.levels), name
        op = operating_point(p)
        # printed to 4 decimals: within half a unit of the last digit
        assert all(abs(x - y) <= 5e-5 for x, y in zip(numbers(cells[6]), op.h[2:])), name
        assert all(abs(x - y) <= 5e-5 for x, y in zip(numbers(cells[7]), op.u)), name
        assert float(cells[8]) == p.height[0] and cells[9] == f"{p.u_range[0]:g}-{p.u_range[1]:g}", name
