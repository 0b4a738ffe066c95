"""Design-parameter sweeps of TITO experiments (heurtune.objectives.tito.sweep)."""

import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import heurtune
from heurtune.core.errors import ConfigError
from heurtune.objectives.tito import model as tito
from heurtune.objectives.tito.sweep import check_sweep, run, run_sweep, sweep_designs

# Two FOPDT loops without interaction and no decoupler: the loop elements are FOPDTs, so their
# two-point fits are exact and the only error of the GPM design is its arctan approximation.
PLANT = """
[plant]
model = "tito"
cases = ["fopdt"]

[plant.custom.fopdt]
g11 = { K = 1.0, lags = [10.0], L = 2.0 }
g12 = { K = 0.0 }
g21 = { K = 0.0 }
g22 = { K = 2.0, lags = [20.0], L = 4.0 }

[decoupler]
type = "none"

[controller]
type = "pi"
baselines = ["gpm"]
gpm = { Am = 3.0, phim = 60.0 }

[scenario]
horizon = 300.0
dt = 0.5
setpoints = [[[0.0, 1.0]], [[50.0, 1.0]]]
input_disturbance = { time = 150.0, size = [0.1, 0.1] }
variation = { "nominal" = 0.0 }
"""


@pytest.fixture(scope="module")
def exp(tmp_path_factory):
    path = tmp_path_factory.mktemp("sweep") / "fopdt_pair.toml"
    path.write_text(PLANT)
    return heurtune.load_experiment(str(path))


def test_gpm_am_sweep_writes_its_files_and_meets_the_spec(exp, tmp_path):
    written = run_sweep(exp, "Am", [2.5, 3.0, 4.0], tmp_path)
    assert [p.name for p in written] == ["sweep_Am.parquet", "sweep_Am_fopdt.png"]
    assert all(p.stat().st_size > 0 for p in written)
    assert written[1].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    t = pd.read_parquet(written[0])
    assert len(t) == 6 and set(t["loop"]) == {1, 2} and list(t["value"].unique()) == [2.5, 3.0, 4.0]
    for col in ("Kp", "Ki", "Kd", "gain_margin", "phase_margin_deg", "Mt", "IAE", "ISE", "ITAE", "Am_spec",
                "phim_spec"):
        assert col in t and t[col].notna().all(), col
    assert (t["design"] == "gpm").all() and (t["Kd"] == 0).all() and (t["status"] == "ok").all()
    assert (t["phim_spec"] == 60.0).all() and (t["Am_spec"] == t["value"]).all()
    # The GPM (Ho-Hang-Cao) design is exact where Ti = T (phim = 90 (1 - 1/Am) deg: (3, 60));
    # elsewhere its arctan approximation misses (measured on these loops: Am 2.534 and 3.951
    # for 2.5 and 4, phim 63.1 and 59.2 deg for 60)
    rel = (t["gain_margin"] / t["value"] - 1.0).abs()
    assert rel[t["value"] == 3.0].max() < 1e-6
    assert (t.loc[t["value"] == 3.0, "phase_margin_deg"] - 60.0).abs().max() < 1e-4
    assert rel.max() < 0.02
    assert (t["phase_margin_deg"] - 60.0).abs().max() < 4.0
    # the designs are the library's GPM PI on each loop
    for _, r in t.iterrows():
        el = exp.problem("fopdt").chain.plant.element(r["loop"], r["loop"])
        Kc, Ti = tito.gpm_pi(tito.FOPDT(el.K, el.lags[0], el.L), r["value"], 60.0)
        assert r["Kp"] == pytest.approx(Kc, rel=1e-7) and r["Ki"] == pytest.approx(Kc / Ti, rel=1e-7)
    # larger Am: smaller gains, slower loops
    loop1 = t[t["loop"] == 1].set_index("value")
    assert loop1["Kp"].is_monotonic_decreasing


def test_gpm_phim_sweep_on_the_exact_line(exp):
    # with Am = 4 held, phim = 67.5 deg lies on the exact line; 50 and 60 within 4 deg
    exp4 = heurtune.load_experiment(exp.config["source"])
    exp4.gpm = {"Am": 4.0, "phim": 60.0}
    t, resp = sweep_designs(exp4, "phim", "50,60,67.5")
    exact = t[t["value"] == 67.5]
    assert np.allclose(exact["gain_margin"], 4.0, rtol=1e-6) and np.allclose(exact["phase_margin_deg"], 67.5,
                                                                              atol=1e-4)
    assert (t["phase_margin_deg"] - t["value"]).abs().max() < 4.0
    assert (t["gain_margin"] / 4.0 - 1.0).abs().max() < 0.04
    assert set(resp["fopdt"]) == {50.0, 60.0, 67.5}
    assert all(df.attrs["status"] == "ok" for df in resp["fopdt"].values())


@pytest.mark.long  # 13 s on the EPYC: `make test` runs the GPM sweep
def test_mt_sweep_as_gamma_m_meets_its_bound(exp, tmp_path):
    written = run_sweep(exp, "gamma_m", [1.2, 1.5], tmp_path, max_evals=500, settings={"starts": 5}, seed=1)
    assert [p.name for p in written] == ["sweep_gamma_m.parquet", "sweep_gamma_m_fopdt.png"]
    t = pd.read_parquet(written[0])
    assert (t["design_param"] == "Mt").all() and (t["param"] == "gamma_m").all()
    assert (t["design"] == "bandwidth").all() and t["feasible"].all() and (t["Mt_spec"] == t["value"]).all()
    # the margin bounds Mt implies (paper 000 eq. 25-26), and Mt itself, hold on every loop
    assert np.allclose(t["Am_spec"], 1.0 + 1.0 / t["value"])
    assert np.allclose(t["phim_spec"], np.degrees(2.0 * np.arcsin(1.0 / (2.0 * t["value"]))))
    assert (t["Mt"] <= t["value"] * (1.0 + 1e-6)).all()
    assert (t["gain_margin"] >= t["Am_spec"] * (1.0 - 1e-3)).all()
    assert (t["phase_margin_deg"] >= t["phim_spec"] * (1.0 - 1e-3)).all()
    # a looser bound never gives a narrower closed loop (each value keeps the best design found)
    wb = t.groupby("value")["w_b"].sum()
    assert wb[1.5] >= wb[1.2]
    assert (t["n_evals"] <= 500).all()


def test_check_sweep_accepts_and_names_the_allowed():
    assert check_sweep("gamma_m", "1.1, 1.3") == ("Mt", (1.1, 1.3))
    assert check_sweep("Am", [2, 3]) == ("Am", (2.0, 3.0))
    bad = [
        (("gain", [2.0]), ("unknown parameter 'gain'", "Am", "phim", "Mt", "gamma_m")),
        (("Am", [1.0]), ("Am = 1.0", "> 1")),
        (("phim", [95.0]), ("phim = 95.0", "(0, 90)")),
        (("Mt", "0.9"), ("Mt = 0.9", "> 1")),
        (("gamma_m", [math.nan]), ("gamma_m = nan", "> 1")),
        (("Am", "2,x"), ("comma-separated numbers",)),
        (("Am", "2,2"), ("given twice",)),
        (("Am", []), ("at least one value",)),
    ]
    for args, words in bad:
        with pytest.raises(ConfigError) as err:
            check_sweep(*args)
        msg = str(err.value)
        assert "\n" not in msg and all(w in msg for w in words), msg


def test_design_errors_name_the_case(exp):
    with pytest.raises(ConfigError, match="unknown case 'nope'.*allowed: fopdt"):
        sweep_designs(exp, "Am", [3.0], cases=["nope"])
    # GPM margins the design cannot meet for L/T = 0.2
    with pytest.raises(ConfigError, match=r"case 'fopdt', Am = 1.5, loop 1: gpm: .*non-positive 1/Ti"):
        sweep_designs(exp, "Am", [1.5])
    # QTS loop 1 has no FOPDT fit, hence no GPM design (docs/tito.md)
    with pytest.raises(ConfigError, match="case 'qts' has no GPM design.*sweep Mt"):
        sweep_designs(heurtune.load_experiment("optimal_pid_qts"), "Am", [3.0])


def test_command_line(exp, tmp_path, capsys):
    src = exp.config["source"]
    assert run([src, "--param", "phim", "--values", "45,60", "--out", str(tmp_path), "--no-figures"]) == 0
    out = capsys.readouterr().out
    assert "sweep_phim.parquet" in out and not list(tmp_path.glob("*.png"))
    assert len(pd.read_parquet(tmp_path / "sweep_phim.parquet")) == 4
    assert run([src, "--param", "Kp", "--values", "1", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "allowed: Am" in err and "gamma_m" in err


def test_import_draws_nothing():
    """Matplotlib is loaded where a figure is written, never when the module is imported."""
    code = ("import sys, heurtune.objectives.tito.sweep; "
            "print('matplotlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_implied_margins_replace_a_bandwidth_experiments_own():
    """paper_000 holds Am >= 2 and phim >= 45 deg, which bind before Mt; with implied_margins the
    sweep holds only what Mt implies (paper 000 eq. 25-26)."""
    from heurtune.objectives.tito.sweep import _mt_constraints

    exp = heurtune.load_experiment("paper_000")
    assert _mt_constraints(exp, 1.6) == {"Am": 2.0, "phim": 45.0, "Mt": 1.6}
    implied = _mt_constraints(exp, 1.6, implied=True)
    assert implied["Am"] == pytest.approx(1.0 + 1.0 / 1.6)
    assert implied["phim"] == pytest.approx(math.degrees(2.0 * math.asin(1.0 / 3.2)))
    assert implied["Mt"] == 1.6
