"""TITO plants, decoupler realisability, FOPDT two-point fit, GPM PI/PID and exact margins."""

import cmath
import math

import numpy as np
import pytest

from heurtune.core.errors import ConfigError
from heurtune.objectives.tito.model import (
    FOPDT,
    PRESETS,
    PIController,
    TFElement,
    TITOPlant,
    exact_margins,
    fit_fopdt,
    gpm_pi,
    gpm_pid,
    inverted_decoupler,
    preset,
)


def test_element_freqresp_is_exact():
    e = TFElement(K=2.0, leads=(3.0,), lags=(10.0, 4.0), L=1.5)
    w = np.array([0.0, 0.1, 2.0])
    s = 1j * w
    expected = 2.0 * (1 + 3 * s) / ((1 + 10 * s) * (1 + 4 * s)) * np.exp(-1.5 * s)
    np.testing.assert_allclose(e.freqresp(w), expected, rtol=1e-14)
    assert e.dc_gain() == 2.0 and e.relative_degree == 1


@pytest.mark.parametrize("kwargs", [
    {"K": math.inf}, {"K": 1.0, "L": -1.0}, {"K": 1.0, "lags": (0.0,)}, {"K": 1.0, "lags": (-2.0,)},
    {"K": 1.0, "leads": (math.nan,)}, {"K": "x"},
])
def test_element_validation(kwargs):
    with pytest.raises(ConfigError):
        TFElement(**kwargs)


def test_plant_from_config_and_errors():
    cfg = {"name": "demo", "g11": {"K": 1.2, "lags": [10, 3], "leads": [], "L": 2},
           "g12": {"K": 0.5, "lags": [8]}, "g21": {"K": 0.3, "lags": [9], "L": 4},
           "g22": {"K": 1.0, "lags": [7], "L": 1}}
    p = TITOPlant.from_config(cfg)
    assert p.name == "demo" and p.g11.lags == (10.0, 3.0) and p.g12.L == 0.0
    fr = p.freqresp([0.0, 0.3])
    assert fr.shape == (2, 2, 2)
    np.testing.assert_allclose(fr[0].real, p.dc_gain())
    bad = [
        ({**cfg, "g33": {}}, "g33"),
        ({k: v for k, v in cfg.items() if k != "g21"}, "g21"),
        ({**cfg, "g12": {"K": 1, "tau": 3}}, "tau"),
        ({**cfg, "g22": {"K": 1, "lags": [-1]}}, "g22"),
        ({**cfg, "g11": {"lags": [1]}}, "g11.K"),
        ({**cfg, "g11": {"K": 1, "lags": "10"}}, "g11.lags"),
    ]
    for c, word in bad:
        with pytest.raises(ConfigError, match=word) as exc:
            TITOPlant.from_config(c)
        assert "\n" not in str(exc.value)
    with pytest.raises(ConfigError, match="allowed: qts"):
        preset("nope")


def test_presets_match_paper_numbers():
    assert set(PRESETS) == {"qts", "ccts", "csts", "two_tank", "wood_berry"}
    q = preset("qts")  # paper 000 eq. 44
    assert (q.g12.K, q.g12.lags, q.g12.L) == (1.39, (10.231, 6.57), 7.0)
    assert (q.g21.K, q.g21.lags, q.g21.L) == (1.271, (14.05, 11.29), 9.0)
    c = preset("ccts")  # paper 000 eq. 49
    assert (c.g11.K, c.g11.lags, c.g11.L, c.g22.K, c.g22.L) == (1.8361, (340.7,), 11.5, 1.89, 12.4)
    s = preset("csts")  # paper 000 eq. 54
    assert s.g12 == s.g21 and s.g12.L == 82.305 and s.g22.lags == (314.47,)
    t = preset("two_tank")  # paper 002 eq. 28
    assert (t.g11.K, t.g12.L, t.g21.L, t.g22.K, t.g22.lags) == (2.197, 9.34, 30.0, 2.82, (602.0,))
    wb = preset("wood_berry")
    np.testing.assert_allclose(wb.dc_gain(), [[12.8, -18.9], [6.6, -19.4]])


def test_decoupler_ratios_match_papers_printed_decouplers():
    # The printed decoupler gains (paper 000 eq. 45, 50, 55) follow from the plants.
    w = np.array([0.0])
    d = inverted_decoupler(preset("qts")).freqresp(w)[0].real
    assert d[0, 1] == pytest.approx(-1.67, abs=5e-3) and d[1, 0] == pytest.approx(-1.678, abs=5e-3)
    assert inverted_decoupler(preset("qts")).ratio_delays == pytest.approx((3.0, 2.0))
    d = inverted_decoupler(preset("ccts")).freqresp(w)[0].real
    assert d[0, 1] == pytest.approx(-0.73 / 1.84, abs=5e-3)


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_decoupler_diagonalises_every_preset(name):
    p = preset(name)
    dec = inverted_decoupler(p)
    assert dec.column_delays == (0.0, 0.0)
    w = np.geomspace(1e-4, 1.0, 50)
    h = p.freqresp(w) @ dec.freqresp(w)
    scale = np.abs(h).max()
    assert np.abs(h[:, 0, 1]).max() < 1e-12 * scale and np.abs(h[:, 1, 0]).max() < 1e-12 * scale
    np.testing.assert_allclose(h[:, 0, 0], dec.z11(w), rtol=1e-12)
    np.testing.assert_allclose(h[:, 1, 1], dec.z22(w), rtol=1e-12)
    g = p.dc_gain()
    assert dec.z11(0.0)[0].real == pytest.approx(g[0, 0] - g[0, 1] * g[1, 0] / g[1, 1])


def _plant(L11=1.0, L12=3.0, L21=4.0, L22=2.0, lags12=(5.0,)):
    return TITOPlant(TFElement(1.0, (), (10.0,), L11), TFElement(0.5, (), lags12, L12),
                     TFElement(0.4, (), (6.0,), L21), TFElement(2.0, (), (8.0,), L22), name="t")


def test_decoupler_realisability_and_delay_compensation():
    with pytest.raises(ConfigError, match=r"-g12/g11 is non-causal"):
        inverted_decoupler(_plant(L11=4.0, L12=1.0))
    with pytest.raises(ConfigError, match=r"-g21/g22 is non-causal"):
        inverted_decoupler(_plant(L21=0.5))
    with pytest.raises(ConfigError, match=r"-g12/g11 is improper"):
        inverted_decoupler(_plant(lags12=()))
    with pytest.raises(ConfigError, match="case must be 1 or 2"):
        inverted_decoupler(_plant(), case=3)
    p = _plant(L11=4.0, L12=1.0, L21=0.5)
    dec = inverted_decoupler(p, delay_compensation=True)
    assert dec.ratio_delays == (-1.5, -3.0) and dec.column_delays == (1.5, 3.0)
    w = np.geomspace(1e-3, 3.0, 40)
    D = dec.freqresp(w)
    h = p.freqresp(w) @ D
    assert np.abs(h[:, 0, 1]).max() < 1e-12 and np.abs(h[:, 1, 0]).max() < 1e-12
    np.testing.assert_allclose(D[:, 0, 0], np.exp(-1.5j * w))  # p1 delays column 1
    # every decoupler entry is causal: net delay of -g12/g11 e^{-3 s} is 0
    np.testing.assert_allclose(D[:, 0, 1] * np.exp(-0j), -p.g12.rational(w) / p.g11.rational(w) * np.exp(-0j))
    # case 2 (unit off-diagonal) also diagonalises
    dec2 = inverted_decoupler(_plant(), case=2, delay_compensation=True)
    h2 = _plant().freqresp(w) @ dec2.freqresp(w)
    assert np.abs(h2[:, 0, 1]).max() < 1e-12 and np.abs(h2[:, 1, 0]).max() < 1e-12
    np.testing.assert_allclose(h2[:, 0, 0], dec2.z11(w), rtol=1e-12)


def test_fopdt_reference_vector():
    f = fit_fopdt(lambda w: 1.0 / (1.0 + 1j * np.asarray(w)) ** 3)
    assert f.K == pytest.approx(1.0, abs=1e-12)
    assert f.wp == pytest.approx(math.sqrt(3.0), abs=1e-6)
    assert f.T == pytest.approx(math.sqrt(21.0), abs=1e-6)
    assert f.T == pytest.approx(4.5826, abs=1e-4)
    assert f.L == pytest.approx((math.pi - math.atan(math.sqrt(63.0))) / math.sqrt(3.0), abs=1e-6)
    assert f.L == pytest.approx(0.9793, abs=1e-4)


FITTABLE = [(n, k) for n in sorted(PRESETS) for k in (1, 2) if (n, k) != ("qts", 1)]


@pytest.mark.parametrize("name,loop", FITTABLE)
def test_fopdt_defining_equations_on_decoupled_presets(name, loop):
    dec = inverted_decoupler(preset(name))
    z = dec.z11 if loop == 1 else dec.z22
    f = fit_fopdt(z)
    assert f.K == pytest.approx(z(0.0)[0].real, rel=1e-12)
    zp, fp = z(f.wp)[0], f.freqresp(f.wp)[0]
    assert abs(fp) == pytest.approx(abs(zp), rel=1e-8)
    assert abs(cmath.phase(fp / zp)) < 1e-8
    assert cmath.phase(math.copysign(1.0, f.K) * zp) == pytest.approx(-math.pi, abs=1e-8) or \
        cmath.phase(math.copysign(1.0, f.K) * zp) == pytest.approx(math.pi, abs=1e-8)
    assert f.T > 0 and f.L > 0


def test_fopdt_errors():
    # QTS z11 = g11 - g12 g21/g22 peaks above its DC gain at its phase crossover: no FOPDT fits.
    with pytest.raises(ConfigError, match=r"\|z\(wp\)\| = .* >= \|K\|"):
        fit_fopdt(inverted_decoupler(preset("qts")).z11)
    with pytest.raises(ConfigError, match="no phase crossover"):
        fit_fopdt(lambda w: 1.0 / (1.0 + 1j * np.asarray(w)))
    with pytest.raises(ConfigError, match="real and non-zero"):
        fit_fopdt(lambda w: np.zeros(np.shape(w), dtype=complex))


def test_gpm_pi_reference_example_and_exact_margins():
    f = FOPDT(K=1.0, T=10.0, L=2.0)
    Kc, Ti = gpm_pi(f, 3.0, 60.0)
    assert Kc == pytest.approx(2.6180, abs=1e-4) and Kc == pytest.approx(10 * math.pi / 12, rel=1e-12)
    assert Ti == pytest.approx(10.0, abs=1e-9)
    m = exact_margins(f.freqresp, PIController(Kc, Ti).freqresp)
    assert m.gain_margin == pytest.approx(3.000, abs=1e-3)
    assert m.phase_margin_deg == pytest.approx(60.0, abs=1e-3)
    assert m.w_pc == pytest.approx(math.pi / 4, rel=1e-9) and m.w_gc == pytest.approx(Kc / Ti, rel=1e-9)


def test_gpm_pid_hand_computed_case():
    # K=2, T=5, L=1, Am=4, phim=45 deg: wp = (4 pi/4 + (pi/2) 4 3)/15 = 7 pi/15,
    # Kc = wp T/(Am K) = 7 pi/24, 1/Ti = 2 wp - 4 wp^2/pi + 1/5 = 14 pi/225 + 0.2.
    f = FOPDT(K=2.0, T=5.0, L=1.0)
    pid = gpm_pid(f, 4.0, 45.0)
    assert pid.wp == pytest.approx(7 * math.pi / 15, rel=1e-12)
    assert pid.Kc == pytest.approx(7 * math.pi / 24, rel=1e-12)
    assert pid.Ti == pytest.approx(1.0 / (14 * math.pi / 225 + 0.2), rel=1e-12)
    assert (pid.Td, pid.Tf) == (pid.Ti, pid.Ti)  # paper 001 eq. 22 and 27 taken literally
    assert gpm_pi(f, 4.0, 45.0) == pytest.approx((pid.Kc, pid.Ti), rel=1e-12)
    w = np.geomspace(1e-3, 10, 30)
    np.testing.assert_allclose(pid.freqresp(w), PIController(pid.Kc, pid.Ti).freqresp(w), rtol=1e-12)
    filt = gpm_pid(f, 4.0, 45.0, Td=0.5)
    assert filt.Tf == pytest.approx(0.005) and filt.parallel()[2] == pytest.approx(filt.Kc * 0.5)
    kp, ki, kd = gpm_pid(f, 4.0, 45.0, Td=0.5, N=1e12).parallel()
    s = 1j * w
    np.testing.assert_allclose(kp + ki / s + kd * s, gpm_pid(f, 4.0, 45.0, Td=0.5, N=1e12).freqresp(w), rtol=1e-9)
    # the arctan approximation: achieved margins close to, not exactly at, the specification
    m = exact_margins(f.freqresp, pid.freqresp)
    assert abs(m.gain_margin - 4.0) < 0.5 and abs(m.phase_margin_deg - 45.0) < 5.0


def test_gpm_validation():
    f = FOPDT(K=1.0, T=10.0, L=2.0)
    for args in [(1.0, 60.0), (3.0, 0.0), (3.0, 95.0), (math.nan, 60.0)]:
        with pytest.raises(ConfigError):
            gpm_pi(f, *args)
    with pytest.raises(ConfigError, match="N must"):
        gpm_pid(f, 3.0, 60.0, N=0.5)
    with pytest.raises(ConfigError, match="L > 0"):
        gpm_pi(FOPDT(K=1.0, T=10.0, L=0.0), 3.0, 60.0)
