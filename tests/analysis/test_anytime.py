"""heurtune.anytime: fixed-target times, ERT, ECDF and its area on hand-computed histories."""

import math

import numpy as np
import pandas as pd
import pytest

from heurtune.analysis import anytime


def _history():
    """Three runs of one optimiser on case "c" (budgets 500, 400, 600).

    run 0: feasible throughout, best 10, 5, 2, 1 at 50, 100, 200, 500 evaluations
    run 1: best 8 at 100 evaluations but infeasible (violation 1); 3 at 300 and 400
    run 2: best 20, 10 at 200, 600 evaluations
    """
    rows = []
    for run, epochs in enumerate([[(50, 10, 0), (100, 5, 0), (200, 2, 0), (500, 1, 0)],
                                  [(100, 8, 1), (300, 3, 0), (400, 3, 0)],
                                  [(200, 20, 0), (600, 10, 0)]]):
        for epoch, (n, f, v) in enumerate(epochs):
            rows.append(dict(experiment="e", case="c", algorithm="a", optimiser_index=0, run=run, epoch=epoch,
                             n_evals=n, best_f=float(f), best_violation=float(v)))
    return pd.DataFrame(rows)


def _evals(ft, run, target):
    sel = ft[(ft["run"] == run) & (ft["target"] == target)]
    assert len(sel) == 1
    return sel["evals"].iloc[0]


def test_feasible_best_ignores_values_before_feasibility():
    h = anytime.feasible_best(_history())
    run1 = h[h["run"] == 1]["f_feasible"].tolist()
    assert run1 == [np.inf, 3.0, 3.0]


def test_fixed_target_times():
    ft = anytime.fixed_target(_history(), [10, 8, 5, 0.5])
    assert _evals(ft, 0, 10) == 50 and _evals(ft, 1, 10) == 300 and _evals(ft, 2, 10) == 600
    # run 1's value 8 at 100 evaluations is infeasible: it reaches 8 only at 300
    assert _evals(ft, 0, 8) == 100 and _evals(ft, 1, 8) == 300 and _evals(ft, 2, 8) == np.inf
    assert all(np.isinf(ft.loc[ft["target"] == 0.5, "evals"]))
    assert ft.groupby("run")["budget"].first().tolist() == [500, 400, 600]
    assert ft["reached"].tolist() == list(np.isfinite(ft["evals"]))


def test_ert_hand_computed():
    e = anytime.ert(anytime.fixed_target(_history(), [10, 5, 3, 0.5])).set_index("target")
    # target 5: hits at 100 and 300, run 2 fails and adds its budget 600
    assert e.loc[5.0, "ert"] == pytest.approx((100 + 300 + 600) / 2)
    assert e.loc[5.0, "successes"] == 2 and e.loc[5.0, "success_rate"] == pytest.approx(2 / 3)
    assert e.loc[10.0, "ert"] == pytest.approx((50 + 300 + 600) / 3)
    assert e.loc[3.0, "ert"] == pytest.approx((200 + 300 + 600) / 2)
    assert np.isinf(e.loc[0.5, "ert"]) and e.loc[0.5, "evals_spent"] == 500 + 400 + 600


def test_ert_of_the_brief():
    # two runs hitting at 100 and 300 evaluations, budgets 500 and 400 -> 200
    h = pd.DataFrame(dict(case="c", algorithm="a", run=[0, 0, 1, 1], n_evals=[100, 500, 300, 400],
                          best_f=[1.0, 1.0, 1.0, 1.0]))
    e = anytime.ert(anytime.fixed_target(h, [1.0]))
    assert e["ert"].iloc[0] == pytest.approx(200.0)
    assert "best_violation" not in h  # unconstrained histories: every value counts


def test_default_targets():
    t = anytime.default_targets(_history(), n_targets=3)
    # best feasible 1; reference: the worst first feasible value of a run (20, run 2)
    np.testing.assert_allclose(t["target"], [20.0, math.sqrt(20.0), 1.0])
    t = anytime.default_targets(_history(), n_targets=2, reference={"c": 100.0})
    np.testing.assert_allclose(t["target"], [100.0, 1.0])
    with pytest.raises(ValueError, match="positive"):
        anytime.default_targets(_history().assign(best_f=lambda d: d["best_f"] - 5))
    with pytest.raises(ValueError, match="n_targets"):
        anytime.default_targets(_history(), n_targets=0)


def test_ecdf_fraction_of_pairs():
    ft = anytime.fixed_target(_history(), [10, 5])
    # evaluations of the 6 pairs: 50, 100 | 300, 300 | 600, inf
    e = anytime.ecdf(ft, budgets=[49, 50, 100, 300, 600, 1000]).set_index("budget")["fraction"]
    assert e.tolist() == pytest.approx([0, 1 / 6, 2 / 6, 4 / 6, 5 / 6, 5 / 6])
    grid = anytime.budget_grid(ft, 10)
    assert grid["budget"].iloc[0] == 50 and grid["budget"].iloc[-1] == 600 and len(grid) == 10


def test_auc_exact_and_against_a_fine_grid():
    ft = anytime.fixed_target(_history(), [10, 5])
    auc = anytime.ecdf_auc(ft, budget_range=(10, 1000))["auc"].iloc[0]
    by_hand = (math.log10(1000 / 50) + math.log10(1000 / 100) + 2 * math.log10(1000 / 300)
               + math.log10(1000 / 600)) / 2 / 6
    assert auc == pytest.approx(by_hand)
    fine = np.geomspace(10, 1000, 200001)
    mean = anytime.ecdf(ft, budgets=fine)["fraction"].mean()
    assert auc == pytest.approx(mean, abs=1e-4)


def test_auc_extremes():
    h = pd.DataFrame(dict(case="c", algorithm="a", run=[0, 1], n_evals=[10, 100], best_f=[1.0, 1.0]))
    ft = anytime.fixed_target(h, [1.0])
    a = anytime.ecdf_auc(ft, budget_range=(10, 1000))["auc"].iloc[0]
    assert a == pytest.approx((1.0 + 0.5) / 2)  # at b_min: 1; at the geometric middle: 0.5
    assert anytime.ecdf_auc(ft, budget_range=(1, 5))["auc"].iloc[0] == 0.0
    assert anytime.ecdf_auc(ft, budget_range=(100, 100))["auc"].iloc[0] == 1.0


def test_optimisers_are_kept_apart_and_plots(tmp_path):
    h = pd.concat([_history(), _history().assign(optimiser_index=1, best_f=lambda d: d["best_f"] * 2)])
    ft = anytime.fixed_target(h, [10.0])
    e = anytime.ert(ft).set_index("optimiser_index")["ert"]
    assert e[0] == pytest.approx((50 + 300 + 600) / 3)
    assert e[1] == pytest.approx((100 + 300 + 600) / 2)  # doubled: 10 at 100, 6 at 300, run 2 fails
    tables = anytime.write_report(h, tmp_path, n_targets=5, n_budgets=8)
    assert set(tables["auc"]["optimiser_index"]) == {0, 1}
    for name in ("anytime_ert.csv", "anytime_ecdf.csv", "anytime_auc.csv", "ecdf_c.png", "fixed_target_c.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert (tmp_path / "ecdf_c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli(tmp_path, capsys):
    _history().to_parquet(tmp_path / "history.parquet")
    assert anytime.run([str(tmp_path), "--targets", "4", "--no-figures"]) == 0
    assert (tmp_path / "anytime_ert.csv").exists() and not list(tmp_path.glob("*.png"))
    assert anytime.run([str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and err.count("\n") == 1
    assert anytime.run([str(tmp_path), "--targets", "0"]) == 2


def test_an_empty_ecdf_or_ert_panel_says_why(tmp_path, monkeypatch):
    """A case none of whose runs has a feasible value has nothing to draw: the panel says so."""
    import pandas as pd
    from figure_helpers import keep_figures

    from heurtune.analysis import anytime, figures

    figs = keep_figures(monkeypatch, figures)
    empty_ecdf = pd.DataFrame(columns=["case", "algorithm", "optimiser_index", "budget", "fraction"])
    anytime.plot_ecdf(empty_ecdf, tmp_path / "e.png", case="nmp")
    empty_ert = pd.DataFrame(
        dict(case=["nmp"], algorithm=["cs"], optimiser_index=[0], target=[1.0], ert=[float("inf")])
    )
    anytime.plot_fixed_target(empty_ert, tmp_path / "f.png", case="nmp")
    texts = [[t.get_text() for t in fig.axes[0].texts] for fig in figs]
    assert texts[0] == ["no run of case nmp has a feasible value: no target to reach"]
    assert texts[1] == ["no run reached any target: every ERT is infinite"]
