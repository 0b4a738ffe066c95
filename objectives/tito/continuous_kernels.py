"""Numba kernel of the continuous TITO loop (``heurtune.objectives.tito.continuous``).

Arrays in, arrays out; everything a step needs is precomputed by the caller. Signals are stored
per step as their values at the ``q`` Gauss-Lobatto nodes, in ``hist[step, signal, node]`` with
signals 0, 1 the errors ``e_1, e_2`` and 2, 3 the input disturbances. A path ``p`` is a state
space of ``nst[p]`` states driven by signal ``src[p]`` delayed by ``shift[p]`` whole steps
(``split[p] = 0``) or by a fraction (``split[p] = 1``: two sub-steps, the first ending at node
``nfirst[p]``, with stored steps ``k - lag[p]`` and ``k - lag[p] + 1`` as inputs). Its output goes
to ``target[p]`` (0: ``y``, 1: ``u``, 2: ``v``) at index ``out[p]``.
"""

import numpy as np
from numba import njit

TARGET_Y = 0
TARGET_U = 1
TARGET_V = 2


@njit(cache=True)
def _inputs(p, k, hist, src, split, shift, lag, PA, PB, QA, QB, wa, wb, wn):
    """Fill ``wa`` (first sub-step or whole step inputs at the nodes), ``wb`` (second sub-step)
    and ``wn`` (the input at the step's own nodes, for the feedthrough)."""
    q = wa.size
    s = src[p]
    if split[p] == 0:
        m = k - shift[p]
        for i in range(q):
            v = hist[m, s, i] if m >= 0 else 0.0
            wa[i] = v
            wn[i] = v
        return
    m2 = k - lag[p] + 1
    m1 = m2 - 1
    for i in range(q):
        a = 0.0
        b = 0.0
        na = 0.0
        nb = 0.0
        for c in range(q):
            h1 = hist[m1, s, c] if m1 >= 0 else 0.0
            h2 = hist[m2, s, c] if m2 >= 0 else 0.0
            a += PA[p, i, c] * h1
            b += PB[p, i, c] * h2
            na += QA[p, i, c] * h1
            nb += QB[p, i, c] * h2
        wa[i] = a
        wb[i] = b
        wn[i] = na + nb


@njit(cache=True, inline="always")
def _affine(E, H, p, i, n, x, w, out, row):
    """``out[row, :n] = E[p, i] x + H[p, i] w`` (a path's state at one node)."""
    for r in range(n):
        acc = 0.0
        for c in range(n):
            acc += E[p, i, r, c] * x[c]
        for c in range(w.size):
            acc += H[p, i, r, c] * w[c]
        out[row, r] = acc


@njit(cache=True)
def _advance(p, x, wa, wb, split, nst, nfirst, E, H, EA, HA, EB, HB, X):
    """Node states ``X[i, :]`` of path ``p`` over the step from its state ``x[p]``."""
    q = wa.size
    n = nst[p]
    if split[p] == 0:
        for i in range(q):
            _affine(E, H, p, i, n, x[p], wa, X, i)
        return
    nf = nfirst[p]
    # first sub-step: nodes 0 .. nf - 1, then its end (row nf of EA/HA) into row nf of X, which
    # the second sub-step starts from and then overwrites with its own first node
    for i in range(nf + 1):
        _affine(EA, HA, p, i, n, x[p], wa, X, i)
    xm = X[nf, :n].copy()
    for i in range(q - nf):
        _affine(EB, HB, p, i, n, xm, wb, X, nf + i)


@njit(cache=True)
def run_loop(n, hist, r_step, dout_step, target, out, src, split, shift, lag, nfirst, nst,
             E, H, EA, HA, EB, HB, PA, PB, QA, QB, C, D, x, y_rec, u_rec, v_rec):
    """Run ``n`` steps; records ``y``, ``u``, ``v`` at the step boundaries (rows ``0 .. n``).

    ``r_step``, ``dout_step``: (n, 2) set-points and output disturbances on each step (constant
    there); ``x``: (paths, max states) zero on entry, updated in place; ``hist`` holds the input
    disturbances (signals 2, 3) on entry and gets the errors (signals 0, 1)."""
    P = target.size
    q = hist.shape[2]
    nmax = x.shape[1]
    X = np.zeros((q, nmax))
    wa = np.zeros(q)
    wb = np.zeros(q)
    wn = np.zeros(q)
    y = np.zeros((2, q))
    u = np.zeros((2, q))
    v = np.zeros((2, q))
    for k in range(n):
        for i in range(2):
            for j in range(q):
                y[i, j] = dout_step[k, i]
                u[i, j] = 0.0
                v[i, j] = 0.0
        for stage in range(3):
            if stage == 1:  # the errors of this step, now that y is known at its nodes
                for i in range(2):
                    for j in range(q):
                        hist[k, i, j] = r_step[k, i] - y[i, j]
            for p in range(P):
                if target[p] != stage:
                    continue
                _inputs(p, k, hist, src, split, shift, lag, PA, PB, QA, QB, wa, wb, wn)
                _advance(p, x, wa, wb, split, nst, nfirst, E, H, EA, HA, EB, HB, X)
                o = out[p]
                for i in range(q):
                    acc = D[p] * wn[i]
                    for r in range(nst[p]):
                        acc += C[p, r] * X[i, r]
                    if stage == 0:
                        y[o, i] += acc
                    elif stage == 1:
                        u[o, i] += acc
                    else:
                        v[o, i] += acc
                for r in range(nst[p]):
                    x[p, r] = X[q - 1, r]
        for i in range(2):
            y_rec[k, i] = y[i, 0]
            u_rec[k, i] = u[i, 0]
            v_rec[k, i] = v[i, 0]
            if k == n - 1:
                y_rec[n, i] = y[i, q - 1]
                u_rec[n, i] = u[i, q - 1]
                v_rec[n, i] = v[i, q - 1]
