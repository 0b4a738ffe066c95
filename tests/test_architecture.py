"""The layout's rules: no import cycles (function-level imports included), every folder of
plant families registers its family, and the commands users type stay where the README says."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Import name -> folder (pyproject's package-dir).
PACKAGES = {"heurtune": ROOT / "heurtune", "heurtune.algorithms": ROOT / "algorithms",
            "heurtune.objectives": ROOT / "objectives"}


def _modules() -> dict:
    mods = {}
    for prefix, folder in PACKAGES.items():
        for path in folder.rglob("*.py"):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join([prefix] + parts)] = path
    return mods


def _imports(name: str, path: Path, mods: dict) -> set:
    """Modules of the package that ``name`` imports anywhere in its file (lazy imports too)."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        for target in targets:
            while target and target not in mods:
                target = target.rpartition(".")[0]
            if target and target != name and not name.startswith(target + "."):
                out.add(target)
    return out


def _cycles(graph: dict) -> list:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles():
    mods = _modules()
    graph = {name: _imports(name, path, mods) for name, path in mods.items()}
    assert len(mods) > 50
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_core_knows_no_plant():
    """The core, the runner and the analysis reach plant families only through the family
    registry (which finds the folders of ``heurtune.objectives`` by name)."""
    mods = _modules()
    for name, path in mods.items():
        if name.startswith(("heurtune.core", "heurtune.runner", "heurtune.analysis")):
            bad = [m for m in _imports(name, path, mods) if m.startswith("heurtune.objectives.")]
            assert not bad, f"{name} imports {bad}"


def test_every_family_folder_registers_its_family():
    from heurtune.core.families import families

    folders = {p.name for p in (ROOT / "objectives").iterdir() if (p / "family.py").is_file()}
    assert folders == {"qtp", "tito"}
    assert folders <= {f.name for f in families()}


def test_commands_run_from_their_documented_names():
    """``python -m heurtune.<command>`` runs the command module's ``main`` (the tests of each
    command run some of them as subprocesses)."""
    commands = {"experiment": "heurtune.runner.experiment", "evaluate": "heurtune.runner.evaluate",
                "compare": "heurtune.analysis.compare", "anytime": "heurtune.analysis.anytime",
                "export": "heurtune.analysis.export", "report": "heurtune.analysis.report",
                "check_plugin": "heurtune.runner.check_plugin", "precompile": "heurtune.runner.precompile"}
    for command, module in commands.items():
        shim = importlib.import_module(f"heurtune.{command}")
        assert shim.main is importlib.import_module(module).main, command
        assert 'if __name__ == "__main__":\n    main()' in Path(shim.__file__).read_text(), command


def test_import_heurtune_loads_no_plant_family_and_no_plotting():
    """``import heurtune`` is light: no plant family (each loads when a config names it), no
    numba kernels, no matplotlib (0.5 s here instead of 2.1-2.9 s when it imported the QTP
    family, its thesis tables and figures); ``heurtune.Experiment`` still resolves, on first use."""
    import subprocess
    import sys

    script = ("import sys, heurtune\n"
              "heavy = [m for m in sys.modules if m.startswith(('heurtune.objectives.', 'matplotlib', 'numba'))]\n"
              "assert not heavy, heavy\n"
              "assert heurtune.Experiment.__module__ == 'heurtune.objectives.qtp.family'\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


def test_a_config_loads_only_the_family_of_its_plant():
    """A QTP config imports the QTP family, not the TITO one (scipy.signal with it: 1.7 s of a
    command's start); a model no family has loads them all and the error names every model."""
    import subprocess
    import sys

    script = ("import sys\n"
              "from heurtune.core.errors import ConfigError\n"
              "from heurtune.core.families import available, get_family\n"
              "assert get_family('qtp').name == 'qtp'\n"
              "assert 'heurtune.objectives.tito.family' not in sys.modules\n"
              "try:\n    get_family('no_such_plant')\nexcept ConfigError as e:\n    message = str(e)\n"
              "assert 'heurtune.objectives.tito.family' in sys.modules\n"
              "assert all(m in message for m in available()) and 'tito' in available(), message\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
