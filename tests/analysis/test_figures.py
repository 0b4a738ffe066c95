"""Result figures (heurtune.analysis.figures): each writes one valid PNG and leaves no temporary file."""

import numpy as np
import pandas as pd
import pytest
from figure_helpers import keep_figures

import heurtune
from heurtune.analysis.figures import FAILED_THRESHOLD, _needs_log, boxplot_figure, convergence_figure, response_figure

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
THESIS_X = ("Q11=0.4431,Q22=0.3027,Q33=0.4434,Q44=1.5722,R11=4.2253,R22=2.5994,"
            "Ki1=1.7411,Ki2=7.1716,alpha1=0.9814,alpha2=0.8437")


def synthetic_history(seed=0):
    """Decaying best-so-far curves; runs of different lengths, some failed early epochs."""
    rng = np.random.default_rng(seed)
    rows = []
    for case, scale in (("min", 3.5e3), ("nmp", 4.0e3)):
        for a, alg in enumerate(("cs", "apso", "ff")):
            for run in range(5):
                n_epochs = 30 + 10 * run + 5 * a
                f = scale * (1 + 2.0 * np.exp(-np.arange(n_epochs) / (5 + 3 * a)))
                f = np.minimum.accumulate(f * (1 + 0.05 * rng.random(n_epochs)))
                if run == 0:
                    f[:3] = 1e10  # no simulable candidate yet
                for e, v in enumerate(f):
                    rows.append(dict(case=case, algorithm=alg, run=run, epoch=e, best_f=v,
                                     n_evals=25 * (e + 1)))
    return pd.DataFrame(rows)


def synthetic_runs(seed=1):
    rng = np.random.default_rng(seed)
    rows = []
    for case in ("min", "nmp"):
        for a, alg in enumerate(("cs", "apso", "ff", "ga")):
            for run in range(10):
                feasible = run != 3 or alg == "cs"
                f = 3.5e3 * (1 + 0.1 * a) + 200 * rng.standard_normal()
                if alg == "ga" and run == 7:
                    f = 1e10  # failed run: left out of the box
                rows.append(dict(case=case, algorithm=alg, run=run, best_f=f, feasible=feasible))
    return pd.DataFrame(rows)


def check_png(path):
    assert path.exists()
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    assert path.stat().st_size > 10_000
    leftovers = [p.name for p in path.parent.iterdir() if p.name.startswith(".")]
    assert leftovers == []


def test_convergence_figure(tmp_path):
    out = tmp_path / "conv" / "convergence.png"
    convergence_figure(synthetic_history(), out)
    check_png(out)


def test_convergence_figure_one_case_and_log_axis(tmp_path):
    # a benchmark-like history spanning six decades, with a wide spread between runs
    h = synthetic_history()
    spread = 1 + h["run"].to_numpy() / 2
    h["best_f"] = np.where(h["best_f"] < FAILED_THRESHOLD,
                           spread * 10.0 ** (-h["epoch"].to_numpy() / 10), h["best_f"])
    out = tmp_path / "conv_min.png"
    convergence_figure(h, out, case=["min"])
    check_png(out)


def test_log_axis_rule():
    assert _needs_log([1e-3, 1.0])
    assert not _needs_log([1.0, 99.0])
    assert not _needs_log([-1.0, 1e3])
    assert not _needs_log([np.nan])


def test_convergence_figure_rejects_bad_input(tmp_path):
    with pytest.raises(ValueError, match="best_f"):
        convergence_figure(pd.DataFrame({"case": [], "algorithm": [], "run": [], "epoch": []}),
                           tmp_path / "x.png")
    with pytest.raises(ValueError, match="no history rows"):
        convergence_figure(synthetic_history(), tmp_path / "x.png", case="P+")
    assert list(tmp_path.iterdir()) == []


def test_boxplot_figure(tmp_path):
    out = tmp_path / "box.png"
    boxplot_figure(synthetic_runs(), out)
    check_png(out)


def test_boxplot_figure_missing_metric(tmp_path):
    with pytest.raises(ValueError, match="J"):
        boxplot_figure(synthetic_runs(), tmp_path / "box.png", metric="J")


def test_response_figure(tmp_path):
    prob = heurtune.load_experiment("cs_folqi_qtp").problem("min")
    out = tmp_path / "resp.png"
    response_figure(prob, prob.parse(THESIS_X), out, title="CS / FOLQI / min")
    check_png(out)


def test_convergence_uses_evaluations_when_epochs_are_unequal_work(tmp_path, monkeypatch):
    from heurtune.analysis import figures

    figs = keep_figures(monkeypatch, figures)
    rows = []
    for alg, per_epoch in (("cs", 50), ("firefly", 100)):
        for run in range(3):
            for epoch in range(5):
                rows.append(dict(case="min", algorithm=alg, run=run, epoch=epoch, n_evals=per_epoch * (epoch + 1),
                                 best_f=10.0 / (epoch + 1) + run))
    history = pd.DataFrame(rows)
    convergence_figure(history, tmp_path / "unequal.png")
    convergence_figure(history.assign(n_evals=50 * (history["epoch"] + 1)), tmp_path / "equal.png")
    assert figs[0].axes[0].get_xlabel() == "evaluations" and figs[1].axes[0].get_xlabel() == "epoch"
    # the firefly line ends at 500 evaluations, the CS line at 250
    ends = sorted(line.get_xdata()[-1] for line in figs[0].axes[0].get_lines())
    assert ends == [250, 500]


def test_empty_panel_says_why_and_axes_carry_units(tmp_path, monkeypatch):
    from heurtune.analysis import figures

    figs = keep_figures(monkeypatch, figures)
    failed = synthetic_history().assign(best_f=1e10)  # no run found a stable candidate
    convergence_figure(failed, tmp_path / "c.png", case="min", failures={"min": ["unstable"] * 15},
                       ylabel="effort J (V² s)")
    ax = figs[0].axes[0]
    assert [t.get_text() for t in ax.texts] == ["no line: 15 runs failed,\nevery best candidate unstable"]
    assert ax.get_ylabel() == "effort J (V² s) (median, IQR band)"
    convergence_figure(failed, tmp_path / "d.png", case="min", failures={"min": ["unstable", "diverged"]})
    assert figs[1].axes[0].texts[0].get_text() == "no line: runs failed, best candidates\n1 unstable, 1 diverged"
    assert heurtune.load_experiment("cs_folqi_qtp").problem("min").objective_label == "effort J (V² s)"


def test_overlapping_scenarios_get_their_own_line_styles(tmp_path, monkeypatch):
    from heurtune.analysis import figures

    figs = keep_figures(monkeypatch, figures)
    t = np.linspace(0, 1, 11)
    traj = pd.concat([pd.DataFrame(dict(scenario=name, t=t, y1=t, y2=t, u1=t, u2=t)) for name in ("a", "b", "c")])
    labels = heurtune.load_experiment("cs_folqi_qtp").problem("min").signal_labels
    figures.plot_responses(traj, tmp_path / "r.png", labels=labels)
    styles = [line.get_linestyle() for line in figs[0].axes[2].get_lines()]  # u1: one line per scenario
    assert len(styles) == 3 and len(set(styles)) == 3
    assert figs[0].axes[2].get_xlabel() == "t (s)" and "(V)" in figs[0].axes[2].get_ylabel()


def test_no_import_or_figure_switches_the_matplotlib_backend(tmp_path):
    """A notebook's backend stays what it was: importing heurtune and its figure modules, and
    writing figures, neither switches pyplot's backend nor imports pyplot (each figure has an
    Agg canvas of its own)."""
    import subprocess
    import sys

    script = f"""
import sys
import matplotlib
before = matplotlib.get_backend()
import heurtune
from heurtune.analysis import figures, anytime
from heurtune.objectives.qtp.thesis import figures as thesis_figures
import pandas as pd
h = pd.DataFrame(dict(case="min", algorithm="cs", optimiser_index=0, run=0, epoch=[0, 1], n_evals=[10, 20],
                      best_f=[2.0, 1.0], best_violation=0.0))
figures.convergence_figure(h, r"{tmp_path / 'c.png'}")
assert matplotlib.get_backend() == before == "svg", (before, matplotlib.get_backend())
assert "matplotlib.pyplot" not in sys.modules
"""
    env = {**__import__("os").environ, "MPLBACKEND": "svg"}
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "c.png").read_bytes()[:4] == b"\x89PNG"


def test_an_algorithm_has_one_colour_in_every_figure(tmp_path, monkeypatch):
    """The convergence figure lists the algorithms in run order, the ECDF in its own: each
    algorithm is drawn in the same colour in both (tab10 in sorted label order)."""
    import matplotlib.colors as mcolors

    from heurtune.analysis import anytime, figures

    figs = keep_figures(monkeypatch, figures)
    rows = []
    for alg in ("pso", "cs", "apso"):  # not sorted
        for run in range(2):
            for epoch in range(4):
                rows.append(dict(case="min", algorithm=alg, optimiser_index=["pso", "cs", "apso"].index(alg), run=run,
                                 epoch=epoch, n_evals=10 * (epoch + 1), best_f=5.0 - epoch - run, best_violation=0.0))
    h = pd.DataFrame(rows)
    figures.convergence_figure(h, tmp_path / "c.png")
    table = anytime.ecdf(anytime.fixed_target(h))
    anytime.plot_ecdf(table.sort_values("algorithm", ascending=False), tmp_path / "e.png", case="min")

    def colours(fig):
        return {line.get_label().split(" ")[0]: mcolors.to_hex(line.get_color())
                for ax in fig.axes for line in ax.get_lines() if not line.get_label().startswith("_")}

    convergence, ecdf = colours(figs[0]), colours(figs[-1])
    assert set(convergence) >= {"pso", "cs", "apso"} and set(ecdf) >= {"pso", "cs", "apso"}
    assert all(convergence[a] == ecdf[a] for a in ("pso", "cs", "apso"))
    assert figures.algorithm_colors(["cs", "apso"]) == figures.algorithm_colors(["apso", "cs", "cs"])


def test_boxplot_counts_failed_and_infeasible_runs_as_compare_does(tmp_path, monkeypatch):
    """A failed run (no stable candidate: the 1e10 sentinel, status "failed") is counted as
    failed, not as infeasible, in the box plot's labels, as in compare's table."""
    from heurtune.analysis import figures

    figs = keep_figures(monkeypatch, figures)
    runs = pd.DataFrame(dict(case="min", algorithm="apso", run=[0, 1, 2], best_f=[1e10, 2.0, 3.0],
                             feasible=[False, False, True], status=["failed", "infeasible", "feasible"]))
    boxplot_figure(runs, tmp_path / "box.png")
    label = figs[0].axes[0].get_xticklabels()[0].get_text()
    assert label == "apso\nn=3, failed=1, infeas.=1"
    # nine algorithms: upright labels that do not run into each other (issue 53)
    many = pd.DataFrame(dict(case="min", algorithm=[f"algorithm_{k}" for k in range(9) for _ in range(2)], run=0,
                             best_f=1.0, feasible=True, status="feasible"))
    boxplot_figure(many, tmp_path / "box9.png")
    fig = figs[1]
    fig.canvas.draw()
    ticks = fig.axes[0].get_xticklabels()
    assert all(t.get_rotation() == 90 for t in ticks)
    boxes = [t.get_window_extent() for t in ticks]
    assert all(not a.overlaps(b) for a, b in zip(boxes, boxes[1:]))
    figs.pop()
    # a case whose every run failed: a note, not empty axes
    boxplot_figure(runs.assign(best_f=1e10, status="failed"), tmp_path / "box2.png")
    assert "every run failed" in " ".join(t.get_text() for t in figs[1].axes[0].texts)


def test_responses_are_sized_from_the_signals(tmp_path, monkeypatch):
    """Three outputs and one input: a 2 x 3 grid, outputs on top, the unused input panels hidden,
    one input range for every input or one per input, a leaving input named in the title."""
    from heurtune.analysis import figures

    figs = keep_figures(monkeypatch, figures)
    t = np.linspace(0, 1, 11)
    traj = pd.DataFrame(dict(scenario="a", t=t, y1=t, y2=2 * t, y3=3 * t, u1=5 * t))
    figures.plot_responses(traj, tmp_path / "r.png", title="T",
                           limits={"y": [(0, 10)] * 3, "u": [(0, 4)]})
    axes = figs[0].axes
    assert len(axes) == 6 and [ax.get_visible() for ax in axes] == [True, True, True, True, False, False]
    assert [ax.get_title() for ax in axes[:3]] == ["output 1", "output 2", "output 3"]
    assert axes[3].get_title() == f"input 1: {figures.OUTSIDE}"
    assert figs[0]._suptitle.get_text() == f"T\n{figures.OUTSIDE}: a"
    figures.plot_responses(traj.assign(u1=t), tmp_path / "s.png", limits={"y": [(0, 10)] * 3, "u": (0, 4)})
    assert figs[1].axes[3].get_title() == "input 1"


def test_off_scale_limits_are_named_in_the_title_and_legends_sit_beside_the_panels(tmp_path, monkeypatch):
    """A limit far from the response is not a legend entry for a line one cannot see: the
    panel's title names it; a limit the response reaches is drawn and in the legend; every
    legend is outside its panel (issue 53)."""
    from heurtune.analysis import figures

    figs = keep_figures(monkeypatch, figures)
    t = np.linspace(0, 1, 11)
    traj = pd.DataFrame(dict(scenario="a", t=t, y1=10 + 0.1 * t, u1=3.5 + 0.6 * t))
    figures.plot_responses(traj, tmp_path / "r.png", limits={"y": [(0, 50)], "u": [(0, 4)]})
    out_ax, in_ax = figs[0].axes[0], figs[0].axes[1]
    assert out_ax.get_title() == "output 1 (limits off scale: 0 and 50)"
    assert [t.get_text() for t in out_ax.get_legend().get_texts()] == ["a: y1"]
    assert "input range 0 to 4" in [t.get_text() for t in in_ax.get_legend().get_texts()]
    for ax in (out_ax, in_ax):
        assert ax.get_legend().get_bbox_to_anchor().x0 >= ax.get_window_extent().x1 - 1


def test_a_long_response_is_drawn_from_its_extremes():
    """A trajectory of 50,000 rows is drawn from a few thousand: each bucket's first and last
    rows and the rows where a signal is smallest or largest, so a one-sample spike and the NaN
    of a diverged tail stay in the figure."""
    from heurtune.analysis.figures import DRAWN_BUCKETS, _drawn_rows

    n = 50_000
    t = np.arange(n) * 0.02
    y = np.sin(t / 30.0)
    y[12_345] = 7.0  # a spike inside a bucket
    u = np.cos(t / 10.0)
    u[-100:] = np.nan
    df = pd.DataFrame({"scenario": "s", "t": t, "y1": y, "u1": u})
    drawn = _drawn_rows(df, ["y1", "u1"])
    assert len(drawn) <= 6 * DRAWN_BUCKETS and drawn.index.is_monotonic_increasing
    assert 12_345 in drawn.index and drawn.index[0] == 0 and drawn.index[-1] == n - 1
    assert drawn["y1"].max() == 7.0 and drawn["y1"].min() == y.min() and np.isnan(drawn["u1"].iloc[-1])
    short = df.iloc[:1000]
    assert _drawn_rows(short, ["y1"]) is short
