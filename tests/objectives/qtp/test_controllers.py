"""LQR gain, (FO)LQI realisation and its sampled (modal / dense) form."""

import control
import numpy as np
import pytest
import scipy.linalg
from numerics import assert_exact, assert_same_bits

from heurtune.objectives.qtp.controllers import ControllerDesignError, lqr_gain
from heurtune.objectives.qtp.model import linearise, preset
from heurtune.objectives.qtp.oustaloup import fractional_integrator
from heurtune.objectives.qtp.structures import build_controller, decision_names, default_bounds

THESIS_CS_FOLQI_MIN = dict(Q11=0.4431, Q22=0.3027, Q33=0.4434, Q44=1.5722, R11=4.2253, R22=2.5994,
                           Ki1=1.7411, Ki2=7.1716, alpha1=0.9814, alpha2=0.8437)


def random_weights(rng):
    return np.diag(rng.uniform(0.01, 2.5, 4)), np.diag(rng.uniform(0.1, 5, 2))


@pytest.mark.parametrize("case", ["min", "nmp", "P-", "P+"])
def test_lqr_gain_matches_scipy_and_python_control(case):
    A, B, _ = linearise(preset(case))
    rng = np.random.default_rng(0)
    for _ in range(5):
        Q, R = random_weights(rng)
        K = lqr_gain(A, B, Q, R)
        K_ctrl, _, _ = control.lqr(A, B, Q, R)
        P = scipy.linalg.solve_continuous_are(A, B, Q, R)
        # Both are backward-stable solvers of a well-conditioned 4x4 CARE: agree to ~1e-12.
        np.testing.assert_allclose(K, K_ctrl, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(K, np.linalg.solve(R, B.T @ P), rtol=1e-9, atol=1e-12)


def test_lqr_failure_is_a_design_error():
    A = np.array([[1.0, 0.0], [0.0, -1.0]])
    B = np.array([[0.0], [1.0]])  # the unstable mode is uncontrollable: no stabilising solution
    with pytest.raises(ControllerDesignError) as info:
        lqr_gain(A, B, np.eye(2), np.eye(1))
    assert info.value.reason == "riccati_failed"


def controller_response(ctrl, w):
    """du = G(jw) w for the controller's state space."""
    n = ctrl.A.shape[0]
    return np.array([ctrl.C @ np.linalg.solve(1j * wi * np.eye(n) - ctrl.A, ctrl.B) + ctrl.D for wi in w])


@pytest.mark.parametrize("realisation", ["direct", "integer_split"])
@pytest.mark.parametrize("alphas", [(0.9814, 0.8437), (1.0, 1.0), (1.5, 0.3)])
def test_folqi_law_matches_equation_3_9(realisation, alphas):
    """du = -K dx + diag(Ki / s^alpha) e with e = -dy: the frequency response, entry by entry."""
    p = preset("min")
    A, B, _ = linearise(p)
    values = dict(THESIS_CS_FOLQI_MIN, alpha1=alphas[0], alpha2=alphas[1])
    ctrl = build_controller("folqi", values, A, B, realisation=realisation)
    K = lqr_gain(A, B, np.diag([values[f"Q{i}{i}"] for i in (1, 2, 3, 4)]), np.diag([values["R11"], values["R22"]]))
    w = np.logspace(-3, 2, 30)
    G = controller_response(ctrl, w)
    for ch in range(2):
        F = values[f"Ki{ch + 1}"] * fractional_integrator(alphas[ch], realisation=realisation).freqresp(w)
        expected = np.tile(-K[ch], (len(w), 1)).astype(complex)
        expected[:, ch] -= F  # e_ch = -dy_ch
        np.testing.assert_allclose(G[:, ch, :], expected, rtol=1e-8, atol=1e-12)


def test_iolqi_is_folqi_with_alpha_one():
    A, B, _ = linearise(preset("nmp"))
    vals = {k: v for k, v in THESIS_CS_FOLQI_MIN.items() if not k.startswith("alpha")}
    io = build_controller("iolqi", vals, A, B)
    fo = build_controller("folqi", dict(vals, alpha1=1.0, alpha2=1.0), A, B)
    for name in ("A", "B", "C", "D"):  # both are folqi_design with alphas (1, 1)
        assert_same_bits(getattr(io, name), getattr(fo, name), because="same code")
    assert io.n_states == 2  # two exact integrators


@pytest.mark.parametrize("alphas, realisation", [
    ((0.9814, 0.8437), "direct"),          # all modal
    ((1.5, 0.4), "integer_split"),         # channel 1 has a double integrator: dense block
    ((2.0, 1.0), "direct"),
])
def test_discretisation_matches_matrix_exponential_of_the_whole_controller(alphas, realisation):
    """Modal and dense block discretisations agree with one expm of the full (A, B)."""
    A, B, _ = linearise(preset("min"))
    ctrl = build_controller("folqi", dict(THESIS_CS_FOLQI_MIN, alpha1=alphas[0], alpha2=alphas[1]),
                            A, B, realisation=realisation)
    dt = 0.01
    dc = ctrl.discretise(dt)
    n = ctrl.n_states
    M = np.zeros((n + 4, n + 4))
    M[:n, :n], M[:n, n:] = ctrl.A, ctrl.B
    E = scipy.linalg.expm(M * dt)
    Ad_ref, Bd_ref = E[:n, :n], E[:n, n:]
    rng = np.random.default_rng(3)
    w = rng.normal(size=(400, 4))
    z_ref = np.zeros(n)
    z = np.zeros(n)
    for k in range(400):
        u_ref = ctrl.C @ z_ref + ctrl.D @ w[k]
        u = dc.Cc @ z + dc.Dc @ w[k]
        # Modal coordinates differ from the cascade ones only by a similarity transform with
        # cond(V) < 1e6; outputs agree to ~1e-10 relative.
        np.testing.assert_allclose(u, u_ref, rtol=1e-9, atol=1e-9)
        z_ref = Ad_ref @ z_ref + Bd_ref @ w[k]
        z = dc.step(z, w[k])
    assert dc.n_states == n and dc.state_channel.shape == (n,)
    assert dc.check_segments()
    # The integrators of e1 and e2 are the kernel's unit-weight segments (all of them when
    # the realisation is fully modal).
    assert dc.segments[2] > 0


def test_decision_names_and_bounds():
    assert decision_names("folqi") == ("Q11", "Q22", "Q33", "Q44", "R11", "R22", "Ki1", "Ki2", "alpha1", "alpha2")
    assert decision_names("iolqi") == decision_names("folqi")[:8]
    assert len(decision_names("ladr")) == 20
    b = default_bounds("folqi")
    assert b["Q11"] == (0.01, 2.5) and b["R22"] == (0.1, 5.0) and b["Ki1"] == (0.1, 10.0) and b["alpha2"] == (0.1, 2.0)
    assert default_bounds("ladr")["beta11"] == (0.0, 150.0)


@pytest.mark.parametrize("alphas, realisation, pairing", [
    ((0.9814, 0.8437), "direct", "diagonal"),
    ((1.5, 0.1), "direct", "anti-diagonal"),  # an exact integrator with the filter; the other pairing
    ((1.0, 1.0), "direct", "diagonal"),        # exact integrators alone
    ((1.5, 0.4), "integer_split", "diagonal"),  # a double integrator: no modal form given
])
def test_folqi_modal_form_is_what_the_matrices_give(alphas, realisation, pairing):
    """FOLQI hands its partial fractions to the simulation as the modal form; they are exactly
    what ``modal_blocks`` derives from (A, B, C), array for array, and the repeated filter of an
    alpha comes from the cache unchanged."""
    import dataclasses

    A, B, _ = linearise(preset("min"))
    values = dict(THESIS_CS_FOLQI_MIN, alpha1=alphas[0], alpha2=alphas[1])
    ctrl = build_controller("folqi", values, A, B, realisation=realisation, pairing=pairing)
    derived = dataclasses.replace(ctrl, modal=None).modal_blocks()
    if realisation == "integer_split":
        assert ctrl.modal is None
        return
    given = ctrl.modal_blocks()
    assert len(given) == len(derived) == 2
    # the matrices written straight from the poles: A diagonal, each state reading its
    # pump's error with weight -1 (e = -w), the outputs the residues times Ki
    errors = (0, 1) if pairing == "diagonal" else (1, 0)
    expected_B = np.zeros((ctrl.n_states, 4))
    expected_C = np.zeros((2, ctrl.n_states))
    for ch, ((start, stop), poles) in enumerate(zip(ctrl.blocks, (g[1] for g in given))):
        assert_exact(np.diag(ctrl.A)[start:stop], poles)  # the poles, copied
        expected_B[start:stop, errors[ch]] = -1.0
        expected_C[ch, start:stop] = values[f"Ki{ch + 1}"] * fractional_integrator(
            alphas[ch], 5, (1e-3, 1e3), realisation).modal()[1]
    assert_exact(ctrl.A, np.diag(np.diag(ctrl.A)))
    assert_exact(ctrl.B, expected_B)
    # the same residues (modal() of the same integrator) times Ki: one product each, compiled or not
    assert_same_bits(ctrl.C, expected_C, because="same code")
    for g, d in zip(given, derived):
        assert g[0] == d[0] == "modal" and g[4:] == d[4:]
        for a, b in zip(g[1:4], d[1:4]):  # modal_blocks reads a diagonal block's arrays: copies
            assert_exact(a, b)
    again = build_controller("folqi", values, A, B, realisation=realisation, pairing=pairing)
    for name in ("A", "B", "C", "D"):
        assert_same_bits(getattr(again, name), getattr(ctrl, name), because="same code")
    # the kernels' form built from the design's concatenated modal arrays is the one built
    # from the blocks, array for array, and writeable (as the kernels were compiled for)
    from heurtune.objectives.qtp.continuous import ContinuousController

    fast = ContinuousController.from_linear(ctrl)
    slow = ContinuousController.from_linear(dataclasses.replace(ctrl, modal_arrays=None))
    assert ctrl.modal_arrays is not None
    for field in dataclasses.fields(ContinuousController):
        a, b = getattr(fast, field.name), getattr(slow, field.name)
        assert a.dtype == b.dtype and a.flags.c_contiguous and a.flags.writeable, field.name
        assert_exact(a, b)  # the same arrays, concatenated once or block by block


def test_weighted_lqr_gains_are_remembered_exactly():
    """The Riccati gains of recent weights are reused: the same bits as ``lqr_gain``, read-only,
    and a failed design fails again with its reason."""
    from heurtune.objectives.qtp import controllers

    A, B, _ = linearise(preset("nmp"))
    q, r = [0.4431, 0.3027, 0.4434, 1.5722], [4.2253, 2.5994]
    K = controllers._weighted_lqr_gain(A, B, q, r)
    # weighted_riccati_gain is riccati_gain on np.diag of the same weights
    assert_same_bits(K, lqr_gain(A, B, np.diag(q), np.diag(r)), because="same code")
    assert controllers._weighted_lqr_gain(A, B, list(q), list(r)) is K and not K.flags.writeable
    assert controllers._weighted_lqr_gain(A, B, q[:3] + [1.5723], r) is not K
    A_bad = np.array([[1.0, 0.0], [0.0, -1.0]])
    B_bad = np.array([[0.0], [1.0]])
    for _ in range(2):
        with pytest.raises(ControllerDesignError) as info:
            controllers._weighted_lqr_gain(A_bad, B_bad, [1.0, 1.0], [1.0])
        assert info.value.reason == "riccati_failed"
