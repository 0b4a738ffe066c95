"""heurtune.export: IOHprofiler files (documented layout, iohinspector if installed) and .mat files."""

import json

import numpy as np
import pandas as pd
import pytest
import scipy.io
from numerics import assert_exact, assert_same_bits

from heurtune.analysis import anytime, export

P = 1.0e10  # the placeholder before a feasible value (FAILED_OBJECTIVE)
X = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994, Ki1=1.7411, Ki2=7.1716,
         alpha1=0.9814, alpha2=0.8437)


def _history():
    rows = []
    runs = {("c1", "pso", 0): [[(50, 10, 0), (100, 5, 0), (200, 5, 0), (500, 1, 0)],
                               [(100, 8, 1), (300, 3, 0), (400, 3, 0)]],
            ("c1", "ga", 1): [[(20, 30, 2), (40, 30, 1)]],  # never feasible
            ("c2", "pso", 0): [[(1, 7, 0), (11, 6, 0)]]}
    for (case, alg, oi), rr in runs.items():
        for run, epochs in enumerate(rr):
            for epoch, (n, f, v) in enumerate(epochs):
                rows.append(dict(experiment="exp", case=case, algorithm=alg, optimiser_index=oi, run=run,
                                 epoch=epoch, n_evals=n, best_f=float(f), best_violation=float(v)))
    return pd.DataFrame(rows)


def test_ioh_lines():
    assert export.ioh_lines([50, 100, 200, 500], [10, 5, 5, 1], P) == [(1, P), (50, 10), (100, 5), (500, 1)]
    assert export.ioh_lines([100, 300, 400], [np.inf, 3, 3], P) == [(1, P), (300, 3), (400, 3)]
    assert export.ioh_lines([20, 40], [np.inf, np.inf], P) == [(1, P), (40, P)]
    assert export.ioh_lines([1, 11], [7, 6], P) == [(1, 7), (11, 6)]


def _parse_dat(path):
    """Runs of an IOHprofiler .dat file: a header line starts each run (the documented layout)."""
    runs = []
    for line in path.read_text().splitlines():
        if line.split() == ["evaluations", "raw_y"]:
            runs.append([])
        else:
            e, y = line.split()
            runs[-1].append((int(e), float(y)))
    return runs


def test_ioh_layout(tmp_path):
    h = _history()
    files = export.write_ioh(h, tmp_path, dimensions={"c1": 3, "c2": 2})
    names = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file())
    assert names == ["ga/IOHprofiler_f1_c1.json", "ga/data_f1_c1/IOHprofiler_f1_DIM3.dat",
                     "pso/IOHprofiler_f1_c1.json", "pso/IOHprofiler_f2_c2.json",
                     "pso/data_f1_c1/IOHprofiler_f1_DIM3.dat", "pso/data_f2_c2/IOHprofiler_f2_DIM2.dat"]
    assert len(files) == 3
    meta = json.loads((tmp_path / "pso/IOHprofiler_f1_c1.json").read_text())
    for key in ("version", "suite", "function_id", "function_name", "maximization", "algorithm", "attributes",
                "scenarios"):
        assert key in meta
    assert (meta["suite"], meta["function_id"], meta["function_name"], meta["maximization"]) == ("exp", 1, "c1", False)
    assert meta["algorithm"]["name"] == "pso" and meta["attributes"] == ["evaluations", "raw_y"]
    (scen,) = meta["scenarios"]
    assert scen["dimension"] == 3
    runs = _parse_dat(tmp_path / "pso" / scen["path"])
    # the placeholder plus the run's place in its file
    assert runs == [[(1, P), (50, 10), (100, 5), (500, 1)], [(1, P + 1), (300, 3), (400, 3)]]
    assert [r["evals"] for r in scen["runs"]] == [500, 400]
    assert [r["best"]["y"] for r in scen["runs"]] == [1, 3]
    assert [r["best"]["evals"] for r in scen["runs"]] == [500, 300]
    assert all(r["instance"] == 0 for r in scen["runs"])
    ga = _parse_dat(tmp_path / "ga/data_f1_c1/IOHprofiler_f1_DIM3.dat")
    assert ga == [[(1, P), (40, P)]]


def test_ioh_keeps_the_fixed_target_times(tmp_path):
    """ERT computed from the written files equals the one from the history (targets below P)."""
    h = _history()
    export.write_ioh(h, tmp_path, dimensions=3)
    rows = []
    for meta_path in tmp_path.rglob("*.json"):
        meta = json.loads(meta_path.read_text())
        for scen in meta["scenarios"]:
            for run, lines in enumerate(_parse_dat(meta_path.parent / scen["path"])):
                rows += [dict(case=meta["function_name"], algorithm=meta["algorithm"]["name"], run=run,
                              n_evals=e, best_f=y) for e, y in lines]
    back = pd.DataFrame(rows)
    targets = [10, 8, 5, 3, 1, 0.5]
    a = anytime.ert(anytime.fixed_target(h, targets)).drop(columns=["experiment", "optimiser_index"])
    b = anytime.ert(anytime.fixed_target(back, targets))
    key = ["case", "algorithm", "target"]
    # the same function on the same integer counts (the IOH files hold them as written)
    a, b = a.sort_values(key).reset_index(drop=True), b.sort_values(key).reset_index(drop=True)
    assert_same_bits(a, b, because="same code")


def test_ioh_read_by_iohinspector(tmp_path):
    iohinspector = pytest.importorskip("iohinspector")
    export.write_ioh(_history(), tmp_path, dimensions=3)
    dm = iohinspector.DataManager()
    dm.add_folder(str(tmp_path))
    ov = dm.overview.to_pandas()
    assert sorted(set(ov["algorithm_name"])) == ["ga", "pso"] and len(ov) == 4
    assert sorted(ov["best_y"]) == [1.0, 3.0, 6.0, P]
    data = dm.load(monotonic=True, include_meta_data=True).to_pandas()
    pso = data[(data["algorithm_name"] == "pso") & (data["function_name"] == "c1")]
    assert sorted(pso.groupby("run_id")["evaluations"].max()) == [300, 500]


def test_iohinspector_keeps_failed_runs_one_after_another(tmp_path):
    """Runs that never find a feasible candidate, one after another, each stay a run for
    iohinspector's monotonic load (issue 53: one shared placeholder lost them)."""
    iohinspector = pytest.importorskip("iohinspector")
    rows = [dict(experiment="exp", case="c1", algorithm="cs", optimiser_index=0, run=run, epoch=e, n_evals=n,
                 best_f=f, best_violation=v)
            for run, epochs in enumerate([[(10, 5.0, 0.0), (20, 4.0, 0.0)],
                                          [(10, 9.0, 1.0), (20, 9.0, 1.0)],     # never feasible
                                          [(10, 9.0, 1.0), (20, 9.0, 1.0)],     # never feasible
                                          [(10, 9.0, 1.0), (20, 3.0, 0.0)]])
            for e, (n, f, v) in enumerate(epochs)]
    export.write_ioh(pd.DataFrame(rows), tmp_path, dimensions=2)
    dm = iohinspector.DataManager()
    dm.add_folder(str(tmp_path))
    data = dm.load(monotonic=True, include_meta_data=True).to_pandas()
    assert data["run_id"].nunique() == 4
    final = data.groupby("run_id")["raw_y"].min().sort_index().to_numpy()
    assert final[0] == 4.0 and final[3] == 3.0 and (final[1:3] >= P).all()


def test_matlab_names():
    assert export.matlab_name("Mp1@+30%") == "Mp1_at_p30pct"
    assert export.matlab_name("J@-30%") == "J_at_m30pct"
    assert export.matlab_name("_x") == "x" and export.matlab_name("1a") == "x1a"
    assert len(export.matlab_name("a" * 100)) == 63


def _results(tmp_path):
    """A results folder of cs_folqi_qtp with two hand-made runs of case min (no optimisation)."""
    from heurtune.runner.config import load_config

    config = load_config("cs_folqi_qtp")
    runs = pd.DataFrame([dict(experiment=config["name"], case="min", algorithm="cs", optimiser_index=0, run=r,
                              best_f=f, feasible=ok, violation=0.0 if ok else 1.0, n_evals=30, status="feasible",
                              settings="{}", **{"Mp1@+30%": 0.1 * r}, **X)
                         for r, f, ok in [(0, 4300.0, True), (1, 4200.0, False)]])
    h = _history().query("case == 'c2'").assign(case="min", algorithm="cs", experiment=config["name"])
    h = pd.concat([h, h.assign(run=1)])
    runs.to_parquet(tmp_path / "runs.parquet")
    h.to_parquet(tmp_path / "history.parquet")
    (tmp_path / "meta.json").write_text(json.dumps(dict(experiment=config["name"], config=config), default=str))
    return runs, h


def test_mat_export(tmp_path):
    from heurtune.core.families import make_experiment
    from heurtune.runner.config import load_config

    runs, h = _results(tmp_path)
    assert export.run([str(tmp_path), "--format", "mat", "--out", str(tmp_path / "m")]) == 0
    r = scipy.io.loadmat(tmp_path / "m/runs.mat", simplify_cells=True)
    assert list(r["runs"]["case"]) == ["min", "min"]
    # a MAT file read back
    assert_exact(r["runs"]["best_f"], runs["best_f"].to_numpy())
    assert_exact(r["runs"]["Mp1_at_p30pct"], [0.0, 0.1])
    assert ["Mp1_at_p30pct", "Mp1@+30%"] in r["column_names"].tolist()
    hist = scipy.io.loadmat(tmp_path / "m/history.mat", simplify_cells=True)["history"]
    assert_exact(hist["n_evals"], h["n_evals"].to_numpy())
    (best,) = [scipy.io.loadmat(tmp_path / "m/best.mat", simplify_cells=True)["best"]]
    assert best["run"] == 0 and best["best_f"] == 4300.0  # the feasible run, not the lower infeasible one
    assert list(best["gain_names"]) == list(X)
    assert_exact(best["gains"], list(X.values()))
    prob = make_experiment(load_config("cs_folqi_qtp")).problem("min")
    x = np.array(list(X.values()))
    ctrl = prob.loop.controller(X)
    np.testing.assert_allclose(best["controller"]["A"], ctrl.A)
    # the blocks as 1-based inclusive rows, the pumps 1 and 2
    assert_exact(np.atleast_2d(best["controller"]["blocks"]), [(a + 1, b) for a, b in ctrl.blocks])
    assert_exact(best["controller"]["block_pump"], [1, 2])
    # the continuous loop (the default) has no sample period: the controller is discretised at
    # the recorded grid's spacing; the exact zero-order hold of the whole controller
    dt = prob.scenario("nominal").output_dt
    assert best["discrete"]["dt"] == dt and np.isnan(best["scenario"]["sample_time"])
    dc = ctrl.discretise(dt)
    z, zm, w = np.zeros(ctrl.n_states), np.zeros(ctrl.n_states), np.array([0.3, -0.2, 0.1, 0.05])
    for _ in range(5):  # the kernels' modal form and the file's dense one advance alike
        z = best["discrete"]["Phi"] @ z + best["discrete"]["Gamma"] @ w
        zm = dc.step(zm, w)
    du_dense = best["discrete"]["C"] @ z + best["discrete"]["D"] @ w
    du_modal = dc.Cc @ zm + dc.Dc @ w
    np.testing.assert_allclose(du_dense, du_modal, rtol=1e-9, atol=1e-12)
    # the plant and the operating point, enough to rebuild the loop without heurtune
    assert best["plant"]["name"] == "min" and best["plant"]["model"] == "qtp"
    np.testing.assert_allclose(best["plant"]["valve_split"], prob.loop.plant.gamma)
    np.testing.assert_allclose(best["operating_point"]["h0"], prob.loop.op.h)
    np.testing.assert_allclose(best["plant"]["linearisation"]["A"], prob.loop.A)
    assert best["scenario"]["disturbance_time"] == 50.0
    # the closed loop rebuilt from the file's matrices alone has the stability check's poles
    P, K = best["plant"]["linearisation"], best["controller"]
    Acl = np.block([[P["A"] + P["B"] @ K["D"], P["B"] @ K["C"]], [K["B"], K["A"]]])
    assert np.max(np.linalg.eigvals(Acl).real) == pytest.approx(prob.loop.stability_margin(ctrl), rel=1e-9)
    resp = prob.simulate(x, "nominal")
    np.testing.assert_allclose(best["response"]["y1"], resp["y1"])
    np.testing.assert_allclose(best["response"]["t"], resp["t"])
    readme = (tmp_path / "m" / "README.txt").read_text()
    assert "1-based" in readme and "controller.blocks" in readme and "cm^2" in readme
    assert "keeps best_f = 1e+10, a placeholder, not a value" in readme
    # the readme and the units inside the file: a copied best.mat still says what it holds
    inside = scipy.io.loadmat(tmp_path / "m/best.mat", simplify_cells=True)
    assert inside["readme"] == readme
    assert inside["units"]["best_f"] == prob.objective_label and inside["units"]["response_y"] == "cm"
    assert inside["units"]["response_u"] == "V" and inside["units"]["response_t"] == "s"


def test_ioh_export_cli(tmp_path, capsys):
    _results(tmp_path)
    assert export.run([str(tmp_path), "--format", "ioh"]) == 0
    meta = json.loads((tmp_path / "ioh/cs/IOHprofiler_f1_min.json").read_text())
    assert meta["scenarios"][0]["dimension"] == 10
    assert meta["scenarios"][0]["runs"][0]["best"]["x"] == list(X.values())


@pytest.mark.parametrize("args, message", [
    (["--format", "csv"], "unknown format 'csv'; allowed: ioh, mat"),
    (["--format", "mat"], "runs.parquet not found"),
])
def test_cli_errors(tmp_path, capsys, args, message):
    assert export.run([str(tmp_path / "nope")] + args) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and message in err and err.count("\n") == 1
