"""Where the continuous QTP loop's error comes from: ETDRK4 with two splittings of the same loop.

heurtune's continuous loop (``continuous_kernels``) integrates ``Y' = L Y + N(Y)`` exactly in
``L``, which holds the controller's own dynamics and the way its states drive the pumps, and
explicitly in ``N``, which holds the plant (its linear part, the square roots around it) and the
feedback from the levels into the controller (``D w``, ``B w``). Its error is fourth order in
the step with a constant set by that explicit part: for a weakly damped loop the integral loop
(plant and integrators) oscillates through ``N`` for the whole horizon, and the error adds up
(issue 50: IAE 0.11 % low at the default tolerance, converging as h^4 with the step).

This script measures the alternative split: ``L`` the whole loop linearised at the operating
point (plant Jacobian, static feedback, controller input and dynamics), ``N`` only what is left
of the plant's square roots beyond their linearisation. Both are Cox and Matthews' ETDRK4
written here in numpy (matrix phi functions by the exponential of an augmented matrix), on the
plant of ``tests/reference_qtp.py`` (written independently of heurtune) closed by heurtune's
controller matrices, against scipy Radau at rtol 1e-11 on the same equations. Steps are graded
after the disturbance as in heurtune (h/16, h/16, h/8, h/4, h/2). Per case and step: the largest
level error on the step nodes, and the relative error of the IAE of both outputs, each IAE by
the trapezoid rule on the same nodes for the method and for the reference (the difference is the
trajectory's alone, not the quadrature's).

Run with ``python benchmarks/splitting.py`` (about a minute; not part of ``make bench``: it times
nothing, it measures the error constants that decide the next step of the kernel).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import reference_qtp as ref  # noqa: E402
from qtp_cases import IOLQI_NMP, THESIS_MIN, WEAK  # noqa: E402

from heurtune.objectives.qtp.loop import ClosedLoop  # noqa: E402
from heurtune.objectives.qtp.model import preset  # noqa: E402

T_DIST = 50.0
HORIZON = 350.0
GRADED = (1 / 16, 1 / 16, 1 / 8, 1 / 4, 1 / 2)


def phi_matrices(M, k_max=3):
    """``phi_0 .. phi_k_max`` of a square matrix, from the exponential of the augmented matrix."""
    n = M.shape[0]
    big = np.zeros(((k_max + 1) * n, (k_max + 1) * n))
    big[:n, :n] = M
    for k in range(k_max):
        big[k * n:(k + 1) * n, (k + 1) * n:(k + 2) * n] = np.eye(n)
    E = scipy.linalg.expm(big)
    return [E[:n, :n]] + [E[:n, k * n:(k + 1) * n] for k in range(1, k_max + 1)]


class Loop:
    """The disturbed loop after ``T_DIST`` in deviation-free coordinates ``Y = (h, z)``: the
    right-hand side and the two linear parts."""

    def __init__(self, case, kind, gains):
        ctrl = ClosedLoop(preset(case), kind).controller(gains)
        p = preset(case)
        self.P = dict(A=list(p.A), a=list(p.a), k=list(p.k), gamma=list(p.gamma), levels=list(p.levels))
        self.h0, self.u0 = ref.equilibrium(self.P)
        self.Ac, self.Bc, self.Cc, self.Dc = ctrl.A, ctrl.B, ctrl.C, ctrl.D
        self.dist = np.array([1.0, 1.0, 0.0, 0.0])
        Ap, Bp = ref.jacobians(self.P, self.h0, self.u0)
        nz = self.Ac.shape[0]
        n = 4 + nz
        self.controller_split = np.zeros((n, n))
        self.controller_split[:4, 4:] = Bp @ self.Cc
        self.controller_split[4:, 4:] = self.Ac
        self.loop_split = self.controller_split.copy()
        self.loop_split[:4, :4] = Ap + Bp @ self.Dc
        self.loop_split[4:, :4] = self.Bc
        self.Y0 = np.concatenate([self.h0, np.zeros(nz)])

    def rhs(self, Y):
        h, z = Y[:4], Y[4:]
        w = h - self.h0 + self.dist
        u = self.u0 + self.Cc @ z + self.Dc @ w
        return np.concatenate([ref.plant_rhs(h, u, self.P), self.Ac @ z + self.Bc @ w])


def etdrk4(loop, L, h):
    """Nodes and states of ETDRK4 with linear part ``L`` over the disturbed span."""
    tables = {}

    def table(step):
        if step not in tables:
            p, q = phi_matrices(step * L), phi_matrices(step * L / 2)
            tables[step] = (p[0], q[0], step / 2 * q[1], step * (p[1] - 3 * p[2] + 4 * p[3]),
                            step * (p[2] - 2 * p[3]), step * (4 * p[3] - p[2]))
        return tables[step]

    def N(Y):
        return loop.rhs(Y) - L @ Y

    span = HORIZON - T_DIST
    steps = [g * h for g in GRADED] + [h] * int(round((span - h) / h))
    Y, t = loop.Y0.copy(), 0.0
    ts, Ys = [0.0], [Y[:4].copy()]
    for step in steps:
        E, E2, Q, f1, f2, f3 = table(step)
        Nu = N(Y)
        a = E2 @ Y + Q @ Nu
        Na = N(a)
        b = E2 @ Y + Q @ Na
        Nb = N(b)
        c = E2 @ a + Q @ (2 * Nb - Nu)
        Y = E @ Y + f1 @ Nu + 2 * f2 @ (Na + Nb) + f3 @ N(c)
        t += step
        ts.append(t)
        Ys.append(Y[:4].copy())
    return np.array(ts), np.array(Ys)


def errors(loop, reference, ts, Ys):
    R = reference.sol(ts)[:4].T
    level = np.abs(Ys - R).max()
    e = np.abs(Ys[:, :2] - loop.h0[:2] + loop.dist[:2])
    er = np.abs(R[:, :2] - loop.h0[:2] + loop.dist[:2])
    iae = np.abs(np.trapezoid(e, ts, axis=0) / np.trapezoid(er, ts, axis=0) - 1.0).max()
    return level, iae


CASES = {"FOLQI min, thesis gains": ("min", "folqi", THESIS_MIN),
         "FOLQI min, weakly damped": ("min", "folqi", WEAK),
         "IOLQI nmp": ("nmp", "iolqi", IOLQI_NMP)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=float, nargs="+", default=[0.125, 0.25, 0.5, 1.0])
    args = parser.parse_args(argv)
    print("| case | step (s) | controller exact (now): level err (cm), IAE rel. | whole linearised loop exact: "
          "level err (cm), IAE rel. |")
    print("| --- | --- | --- | --- |")
    for label, (case, kind, gains) in CASES.items():
        loop = Loop(case, kind, gains)
        reference = solve_ivp(lambda t, Y, loop=loop: loop.rhs(Y), (0.0, HORIZON - T_DIST), loop.Y0, method="Radau",
                              rtol=1e-11, atol=1e-12, dense_output=True)
        for h in args.steps:
            cells = []
            for L in (loop.controller_split, loop.loop_split):
                with np.errstate(all="ignore"):
                    level, iae = errors(loop, reference, *etdrk4(loop, L, h))
                cells.append(f"{level:.1e}, {iae:.1e}" if np.isfinite(level) and level < 1e3 else "diverges")
            print(f"| {label} | {h:g} | {cells[0]} | {cells[1]} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
