"""An independent continuous-time model of the QTP (FO)LQI loop, integrated with scipy.

Nothing here calls heurtune's simulator, controller builder or Oustaloup code: the plant, the
operating point, the linearisation, the Oustaloup filter (via scipy.signal.zpk2ss) and the LQR
gain (python-control) are all written or obtained anew, so agreement with the jitted loop is a
real check. Used by the tests and by benchmarks/bench_evaluate.py as the speed reference.
"""

from __future__ import annotations

import math

import control
import numpy as np
import scipy.signal
from scipy.integrate import solve_ivp

G = 981.0


def plant_rhs(h, u, P):
    """Johansson's equations, levels clipped at zero under the roots."""
    A, a, k, gm = P["A"], P["a"], P["k"], P["gamma"]
    q = [a[i] * math.sqrt(2 * G * max(h[i], 0.0)) for i in range(4)]
    return np.array([
        (-q[0] + q[2] + gm[0] * k[0] * u[0]) / A[0],
        (-q[1] + q[3] + gm[1] * k[1] * u[1]) / A[1],
        (-q[2] + (1 - gm[1]) * k[1] * u[1]) / A[2],
        (-q[3] + (1 - gm[0]) * k[0] * u[0]) / A[3],
    ])


def equilibrium(P):
    gm, k, a = P["gamma"], P["k"], P["a"]
    h1, h2 = P["levels"]
    M = np.array([[gm[0] * k[0], (1 - gm[1]) * k[1]], [(1 - gm[0]) * k[0], gm[1] * k[1]]])
    u = np.linalg.solve(M, [a[0] * math.sqrt(2 * G * h1), a[1] * math.sqrt(2 * G * h2)])
    h3 = ((1 - gm[1]) * k[1] * u[1] / a[2]) ** 2 / (2 * G)
    h4 = ((1 - gm[0]) * k[0] * u[0] / a[3]) ** 2 / (2 * G)
    return np.array([h1, h2, h3, h4]), u


def jacobians(P, h0, u0, eps=1e-6):
    """Central finite differences of plant_rhs."""
    A = np.zeros((4, 4))
    B = np.zeros((4, 2))
    for j in range(4):
        dh = np.zeros(4)
        dh[j] = eps * max(1.0, h0[j])
        A[:, j] = (plant_rhs(h0 + dh, u0, P) - plant_rhs(h0 - dh, u0, P)) / (2 * dh[j])
    for j in range(2):
        du = np.zeros(2)
        du[j] = eps
        B[:, j] = (plant_rhs(h0, u0 + du, P) - plant_rhs(h0, u0 - du, P)) / (2 * eps)
    return A, B


def frac_integrator_ss(alpha, N=5, wb=1e-3, wh=1e3, realisation="direct"):
    """1/s^alpha as (A, B, C, D) via scipy.signal.zpk2ss (Oustaloup, thesis eq. 3.4)."""
    n_int = math.floor(alpha + 1e-12)
    frac = alpha - n_int
    zeros, poles, gain = [], [], 1.0
    if frac > 1e-12:
        r = -frac if realisation == "direct" else 1 - frac
        if realisation != "direct":
            n_int += 1
        mu = wh / wb
        for kk in range(-N, N + 1):
            zeros.append(-wb * mu ** ((kk + N + 0.5 * (1 - r)) / (2 * N + 1)))
            poles.append(-wb * mu ** ((kk + N + 0.5 * (1 + r)) / (2 * N + 1)))
        gain = wh**r
    poles += [0.0] * n_int
    A, B, C, D = scipy.signal.zpk2ss(zeros, poles, gain)
    return A, B.ravel(), C.ravel(), float(np.squeeze(D))


def reference_loop(P, gains, t_eval, *, d=(1.0, 1.0), t_d=50.0, factor=1.0,
                   realisation="direct", method="Radau", rtol=1e-9, atol=1e-11, integrals=False):
    """Continuous FOLQI loop ``u = u0 - K dx_meas + Ki/s^alpha (-dy_meas)``.

    Parameters
    ----------
    P : dict with A, a, k, gamma, levels (nominal plant)
    gains : dict with Q11..Q44, R11, R22, Ki1, Ki2 and optionally alpha1, alpha2 (default 1)
    t_eval : sample times; d, t_d : measured-level step; factor : scaling of A_i and a_i
    integrals : bool
        Also integrate ``|e1|``, ``|e2|`` and ``e1^2``, ``e2^2`` as four more states of the ODE
        (the solver's own error control on them) and return their values at the last time.

    Returns
    -------
    y : (len(t_eval), 2) measured levels; u : (len(t_eval), 2) pump voltages
    (and with ``integrals``: (4,) IAE1, IAE2, ISE1, ISE2 over [0, t_eval[-1]])
    """
    h0, _ = equilibrium(P)
    A, B = jacobians(P, h0, equilibrium(P)[1])
    Q = np.diag([gains[f"Q{i}{i}"] for i in (1, 2, 3, 4)])
    R = np.diag([gains["R11"], gains["R22"]])
    K, _, _ = control.lqr(A, B, Q, R)
    Pp = dict(P, A=[x * factor for x in P["A"]], a=[x * factor for x in P["a"]])
    _, u0 = equilibrium(Pp)
    filters = [frac_integrator_ss(gains.get(f"alpha{i}", 1.0), realisation=realisation) for i in (1, 2)]
    sizes = [f[0].shape[0] for f in filters]
    ki = (gains["Ki1"], gains["Ki2"])

    def control_law(h, xc, dist):
        w = h - h0
        w[:2] += dist
        u = u0 - K @ w
        e = -w[:2]
        out = []
        off = 0
        for i, (Af, Bf, Cf, Df) in enumerate(filters):
            xf = xc[off:off + sizes[i]]
            u[i] += ki[i] * (Cf @ xf + Df * e[i])
            out.append(Af @ xf + Bf * e[i])
            off += sizes[i]
        return u, np.concatenate(out)

    nq = 4 if integrals else 0

    def rhs(t, s, dist):
        h, xc = s[:4], s[4:len(s) - nq]
        u, dxc = control_law(h.copy(), xc, dist)
        parts = [plant_rhs(h, u, Pp), dxc]
        if integrals:
            e = h[:2] - h0[:2] + dist
            parts.append(np.concatenate([np.abs(e), e * e]))
        return np.concatenate(parts)

    s0 = np.concatenate([h0, np.zeros(sum(sizes) + nq)])
    y = np.empty((len(t_eval), 2))
    u = np.empty((len(t_eval), 2))
    t_eval = np.asarray(t_eval)
    T = t_eval[-1]
    pieces = [(0.0, t_d, np.zeros(2)), (t_d, T, np.asarray(d, dtype=float))]
    for t0, t1, dist in pieces:
        mask = (t_eval >= t0) & ((t_eval < t1) if t1 < T else (t_eval <= t1))
        te = t_eval[mask]
        te_full = te if len(te) and te[-1] >= t1 else np.append(te, t1)
        sol = solve_ivp(rhs, (t0, t1), s0, method=method, t_eval=te_full, args=(dist,),
                        rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(sol.message)
        for j, idx in enumerate(np.flatnonzero(mask)):
            h, xc = sol.y[:4, j], sol.y[4:sol.y.shape[0] - nq, j]
            y[idx] = h[:2] + dist
            u[idx], _ = control_law(h.copy(), xc, dist)
        s0 = sol.y[:, -1]
    if integrals:
        return y, u, s0[len(s0) - 4:]
    return y, u


def fractional_ss(r, N=5, wb=1e-3, wh=1e3):
    """``s^r`` (-1 < r < 1) by Oustaloup's filter as (A, B, C, D), via scipy.signal.zpk2ss."""
    mu = wh / wb
    zeros = [-wb * mu ** ((kk + N + 0.5 * (1 - r)) / (2 * N + 1)) for kk in range(-N, N + 1)]
    poles = [-wb * mu ** ((kk + N + 0.5 * (1 + r)) / (2 * N + 1)) for kk in range(-N, N + 1)]
    A, B, C, D = scipy.signal.zpk2ss(zeros, poles, wh**r)
    return A, B.ravel(), C.ravel(), float(np.squeeze(D))


def reference_pid_loop(P, gains, t_eval, *, kind="pid", pairing="diagonal", decoupler="none", N=10.0,
                       d=(1.0, 1.0), t_d=50.0, method="DOP853", rtol=1e-10, atol=1e-12):
    """Continuous decentralised PID (``kind="pid"``: ``Kp + Ki/s + Kd N s/(s + N)``) or FOPID
    (``"fopid"``: ``Kp + Ki/s^lambda + Kd s^mu``, Oustaloup by zpk2ss) loop on the levels,
    written anew: pump r acts on the error of level r (diagonal) or of the other level
    (anti-diagonal), through the decoupler ``G(0)^-1 M`` (``M`` the paired DC gains, G(0) from
    finite-difference Jacobians) with ``decoupler="inverse_dc"``.

    Returns
    -------
    y : (len(t_eval), 2) measured levels; iae : (2,) IAE of both levels over the run
    """
    h0, u0 = equilibrium(P)
    A, B = jacobians(P, h0, u0)
    err = (0, 1) if pairing == "diagonal" else (1, 0)
    Dd = np.eye(2)
    if decoupler == "inverse_dc":
        G0 = -np.linalg.solve(A, B)[:2]
        M = np.zeros((2, 2))
        for r in range(2):
            M[err[r], r] = G0[err[r], r]
        Dd = np.linalg.solve(G0, M)
    # per loop: a list of (A, B, C, D, gain) parts acting on its error, plus Kp
    loops = []
    for r in range(2):
        g = {k: gains[f"{k}{r + 1}"] for k in ("Kp", "Ki", "Kd")}
        if kind == "pid":
            parts = [(np.zeros((1, 1)), np.ones(1), np.ones(1), 0.0, g["Ki"]),
                     # Kd N (e - x_f), x_f' = N (e - x_f)
                     (np.array([[-N]]), np.array([N]), np.array([-N]), N, g["Kd"])]
        else:
            parts = [frac_integrator_ss(gains[f"lambda{r + 1}"]) + (g["Ki"],),
                     fractional_ss(gains[f"mu{r + 1}"]) + (g["Kd"],)]
        loops.append((g["Kp"], parts))
    sizes = [p[0].shape[0] for _, parts in loops for p in parts]

    def law(h, xc, dist):
        e_all = -(h[:2] + dist - h0[:2])
        v = np.zeros(2)
        dx = []
        off = 0
        k = 0
        for r, (kp, parts) in enumerate(loops):
            e = e_all[err[r]]
            v[r] = kp * e
            for Af, Bf, Cf, Df, gain in parts:
                x = xc[off:off + sizes[k]]
                v[r] += gain * (Cf @ x + Df * e)
                dx.append(Af @ x + Bf * e)
                off += sizes[k]
                k += 1
        return u0 + Dd @ v, np.concatenate(dx)

    def rhs(t, s, dist):
        h, xc = s[:4], s[4:-2]
        u, dxc = law(h, xc, dist)
        return np.concatenate([plant_rhs(h, u, P), dxc, np.abs(h[:2] + dist - h0[:2])])

    s0 = np.concatenate([h0, np.zeros(sum(sizes) + 2)])
    y = np.empty((len(t_eval), 2))
    t_eval = np.asarray(t_eval)
    T = t_eval[-1]
    for t0, t1, dist in [(0.0, t_d, np.zeros(2)), (t_d, T, np.asarray(d, dtype=float))]:
        mask = (t_eval >= t0) & ((t_eval < t1) if t1 < T else (t_eval <= t1))
        te = t_eval[mask]
        te_full = te if len(te) and te[-1] >= t1 else np.append(te, t1)
        sol = solve_ivp(rhs, (t0, t1), s0, method=method, t_eval=te_full, args=(dist,), rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(sol.message)
        y[mask] = sol.y[:2, :mask.sum()].T + dist
        s0 = sol.y[:, -1]
    return y, s0[-2:]


def reference_pi2dof_loop(P, gains, t_eval, *, pairing="diagonal", r=(1.0, 1.0), t_r=10.0, d=(1.0, 1.0),
                          t_d=200.0, rtol=1e-10, atol=1e-12):
    """Decentralised two-degree-of-freedom PI loop, written anew: pump ``j`` acts on level
    ``e_j`` (``j`` diagonal, the other anti-diagonal) by ``u_j = u0_j + Kp_j (b_j r_e - y_e) +
    Ki_j x_j``, ``x_j' = r_e - y_e``, with the set-point deviations ``r`` (cm from the
    operating levels) from ``t_r`` and the measured deviations ``y = h + d - h0`` (``d`` from
    ``t_d``). DOP853 between the steps.

    Returns
    -------
    y : (len(t_eval), 2) measured levels; iae : (2,) IAE of ``r - y`` over the run;
    iae_at : dict of t -> (2,) IAE up to each step time and the end
    """
    h0, u0 = equilibrium(P)
    err = (0, 1) if pairing == "diagonal" else (1, 0)
    g = [{k: gains[f"{k}{j + 1}"] for k in ("Kp", "Ki", "b")} for j in range(2)]

    def rhs(t, s, ref, dist):
        h, x = s[:4], s[4:6]
        y = h[:2] + dist - h0[:2]
        e = ref - y
        u = np.array([u0[j] + g[j]["Kp"] * (g[j]["b"] * ref[err[j]] - y[err[j]]) + g[j]["Ki"] * x[j]
                      for j in range(2)])
        return np.concatenate([plant_rhs(h, u, P), [e[err[0]], e[err[1]]], np.abs(e)])

    T = float(np.asarray(t_eval)[-1])
    edges = sorted({0.0, float(t_r), float(t_d), T})
    s0 = np.concatenate([h0, np.zeros(4)])
    y = np.empty((len(t_eval), 2))
    t_eval = np.asarray(t_eval)
    iae_at = {}
    for t0, t1 in zip(edges[:-1], edges[1:]):
        ref = np.asarray(r, dtype=float) * (t0 >= t_r)
        dist = np.asarray(d, dtype=float) * (t0 >= t_d)
        mask = (t_eval >= t0) & ((t_eval < t1) if t1 < T else (t_eval <= t1))
        te = t_eval[mask]
        te_full = te if len(te) and te[-1] >= t1 else np.append(te, t1)
        sol = solve_ivp(rhs, (t0, t1), s0, method="DOP853", t_eval=te_full, args=(ref, dist), rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(sol.message)
        y[mask] = sol.y[:2, :mask.sum()].T + dist
        s0 = sol.y[:, -1]
        iae_at[t1] = s0[-2:].copy()
    return y, s0[-2:], iae_at
