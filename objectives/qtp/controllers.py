"""Linear controllers of the QTP as continuous-time state-space blocks.

Every controller maps the measured deviations ``w = [y1 - h1o, y2 - h2o, h3 - h3o, h4 - h4o]``
to the pump-voltage deviations ``du`` (the applied voltage is ``u = u_o + du``)::

    z' = A z + B w,    du = C z + D w

with ``A`` block diagonal: block ``b`` occupies states ``blocks[b]`` and is driven by the
whole ``w``; ``block_channel[b]`` names the pump it acts on (used by anti-windup).

Conventions
-----------
(FO)LQI (thesis eq. 3.9)::

    du = -K dx + diag(Ki1 / s^alpha1, Ki2 / s^alpha2) e,   e = r - dy = -dy (regulation)

``K = R^-1 B^T P`` from the CARE of the linearised plant. A positive ``Ki`` integrates the
error ``r - y`` and so removes it (the QTP has positive DC gains). Note python-control's
``lqr(..., integral_action=C)`` integrates ``C x`` instead: its integral gains have the opposite
sign.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import typing

import numpy as np
import scipy.linalg

from heurtune.core.errors import DesignError
from heurtune.core.structures import get_structure
from heurtune.objectives.qtp import design_kernels as _design_kernels
from heurtune.objectives.qtp.oustaloup import fractional_integrator

__all__ = [
    "LinearController",
    "DiscreteController",
    "ControllerDesignError",
    "lqr_gain",
    "PlantLinearisation",
    "folqi_design",
    "lqi_design",
    "ladr_design",
    "LADR_NAMES",
    "PAIRINGS",
    "dc_gain",
    "integral_action_obstruction",
]

N_MEASURED = 4
N_INPUTS = 2
_UNIT_ROWS = np.eye(2)
# Largest Riccati residual accepted, relative to the size of its terms.
RICCATI_RESIDUAL_TOL = 1e-9
# Riccati gains of recent weights (see _weighted_lqr_gain).
_LQR_CACHE_SIZE = 64
_lqr_cache: collections.OrderedDict = collections.OrderedDict()


_PUMP_ROWS = np.array([[False], [True]])  # row r is the unit vector of pump r where unit1 == r
_SEGMENT_KEYS = np.arange(4)
# Largest eigenvector condition number for which a block is simulated in modal form.
MODAL_COND_LIMIT = 1e6


class ControllerDesignError(DesignError):
    """A candidate's controller cannot be built (Riccati failure, invalid parameter)."""

    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason
        self.detail = detail


@dataclasses.dataclass(frozen=True)
class LinearController:
    """Continuous-time linear controller ``z' = A z + B w``, ``du = C z + D w``, and for a
    structure that reads the reference, ``z' = A z + B w + Br r``, ``du = C z + D w + Dr r``.

    ``w`` are the four measured deviations: from the set-points for ``y1``, ``y2`` when the
    controller does not read the reference (``Br``, ``Dr`` None: it sees the errors), from the
    operating levels when it does; ``r`` (2,) the set-point deviations from the operating
    levels, in cm. Stability, margins and the sampled loop use ``A``, ``B``, ``C``, ``D``: the
    reference is an input from outside the loop.

    Attributes
    ----------
    A : (nz, nz) ndarray, block diagonal per ``blocks``
    B : (nz, 4) ndarray
    C : (2, nz) ndarray
    D : (2, 4) ndarray
    blocks : tuple of (start, stop)
    block_channel : tuple of int
    minimal : bool
        False when the realisation may hold uncontrollable or unobservable modes (LADR): the
        stability check then works on a minimal realisation.
    modal : tuple or None
        What :meth:`modal_blocks` returns, when the design knows it already (FOLQI builds its
        fractional integrators in partial fractions): the same arrays, without deriving them
        from ``A``, ``B``, ``C`` again. None: derived.
    modal_arrays : tuple or None
        When every block is modal and the design knows it: the blocks' ``lam``, ``b`` (nz,),
        the measured signal each state reads and the pump it belongs to (nz,) int64,
        concatenated in block order, shared by every controller of one FOLQI layout (never
        write them). None: taken from :meth:`modal_blocks`.
    Br : (nz, 2) ndarray or None
        How the set-point deviations drive the states (a reference filter, set-point weights
        on an integral); None for a structure that does not read the reference.
    Dr : (2, 2) ndarray or None
        How they drive the pumps directly (set-point weights, feedforward).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    blocks: tuple
    block_channel: tuple
    minimal: bool = True
    modal: tuple | None = dataclasses.field(default=None, compare=False, repr=False)
    modal_arrays: tuple | None = dataclasses.field(default=None, compare=False, repr=False)
    Br: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)
    Dr: np.ndarray | None = dataclasses.field(default=None, compare=False, repr=False)

    def __post_init__(self):
        if (self.Br is None) != (self.Dr is None):
            raise ValueError("LinearController: give both Br and Dr (a structure that reads the reference) or neither")
        if self.Br is not None:
            nz = self.A.shape[0]
            if np.shape(self.Br) != (nz, 2) or np.shape(self.Dr) != (2, 2):
                raise ValueError(f"LinearController: Br must be ({nz}, 2) and Dr (2, 2), got "
                                 f"{np.shape(self.Br)} and {np.shape(self.Dr)}")

    @property
    def reads_reference(self) -> bool:
        """Whether the controller has a reference path (``Br``, ``Dr``)."""
        return self.Br is not None

    def reference_feed(self) -> tuple:
        """``(Be, De)``, (nz, 2) and (2, 2): the reference path in the kernels' form, where the
        measured deviations of ``y1``, ``y2`` are taken from the set-points (``w_k = w - [r, 0,
        0]``): ``B w + Br r = B w_k + Be r`` with ``Be = Br + B[:, :2]``, ``De = Dr + D[:, :2]``."""
        return (np.asarray(self.Br, dtype=np.float64) + self.B[:, :2],
                np.asarray(self.Dr, dtype=np.float64) + self.D[:, :2])

    @property
    def n_states(self) -> int:
        return self.A.shape[0]

    def modal_blocks(self) -> list:
        """The controller's blocks in the form the simulation kernels take them.

        A block driven by a single measured signal that is diagonal already (FOLQI builds its
        fractional integrators in partial fractions) or whose eigenvalues are real with a
        well-conditioned eigenvector matrix (``cond(V) < MODAL_COND_LIMIT``) is modal: each of
        its states obeys ``z_i' = lam_i z_i + b_i w_col``. Other blocks (several inputs, complex
        modes, Jordan chains such as a double integrator) stay dense.

        Returns
        -------
        list
            In block order, ``("modal", lam, b, C, col, channel)`` with ``lam``, ``b`` (m,) and
            ``C`` (2, m) the block's output matrix in modal coordinates, or
            ``("dense", A, B, C, channel)`` with the block's own matrices.
        """
        if self.modal is not None:
            return list(self.modal)
        parts = []
        for (start, stop), ch in zip(self.blocks, self.block_channel):
            A = self.A[start:stop, start:stop]
            B = self.B[start:stop]
            C = self.C[:, start:stop]
            cols = np.flatnonzero(B.any(axis=0))
            lam = A.diagonal()
            diagonal = np.count_nonzero(A) == np.count_nonzero(lam)
            V = None
            if not diagonal and len(cols) == 1:
                lam, V = np.linalg.eig(A)
            if len(cols) == 1 and (diagonal or (not np.iscomplexobj(lam)
                                                and np.linalg.cond(V) < MODAL_COND_LIMIT)):
                parts.append(("modal", lam, B[:, cols[0]] if diagonal else np.linalg.solve(V, B[:, cols[0]]),
                              C if diagonal else C @ V, int(cols[0]), ch))
            else:
                parts.append(("dense", A, B, C, ch))
        return parts

    def discretise(self, dt: float) -> DiscreteController:
        """Exact zero-order-hold discretisation, block by block (see :meth:`modal_blocks`):
        each modal state advances by ``z <- a z + b w_col``, a dense block by its matrix
        exponential.
        """
        nw = self.B.shape[1]
        lam_parts, b_parts, C_parts, col_parts, ch_parts = [], [], [], [], []
        dense = []
        for part in self.modal_blocks():
            if part[0] == "modal":
                _, lam, b, C, col, ch = part
                lam_parts.append(lam)
                b_parts.append(b)
                C_parts.append(C)
                col_parts.append(np.full(lam.size, col, dtype=np.int64))
                ch_parts.append(np.full(lam.size, ch, dtype=np.int64))
            else:
                _, A, B, C, ch = part
                n = A.shape[0]
                M = np.zeros((n + nw, n + nw))
                M[:n, :n] = A
                M[:n, n:] = B
                E = scipy.linalg.expm(M * dt)
                dense.append((E[:n, :n], E[:n, n:], C, ch))
        if lam_parts:
            lam = np.concatenate(lam_parts)
            x = lam * dt
            # (e^{lam dt} - 1) / lam, which is dt for lam = 0
            zero = x == 0.0
            phi = np.where(zero, dt, np.expm1(x) / np.where(zero, 1.0, lam))
            a_all, b_all = np.exp(x), phi * np.concatenate(b_parts)
            C_all = np.hstack(C_parts)
            cols, ch_all = np.concatenate(col_parts), np.concatenate(ch_parts)
            # A modal state read from measured signal r that drives pump r only (r = 0, 1: the
            # integrators of the errors e1, e2) is rescaled so that its output weight is 1
            # (z' = c z): the kernel adds those up without products. Order (``segments``):
            # those of pump 0, those of pump 1, the other modal states, then the dense blocks.
            c0, c1 = C_all
            unit0 = (cols == 0) & (c1 == 0.0) & (c0 != 0.0)
            unit1 = (cols == 1) & (c0 == 0.0) & (c1 != 0.0)
            b_all = np.where(unit0, b_all * c0, np.where(unit1, b_all * c1, b_all))
            key = np.where(unit0, 0, np.where(unit1, 1, 2))
            perm = np.argsort(key, kind="stable")
            C_all = np.where(unit0 | unit1, (unit1[None, :] == _PUMP_ROWS), C_all)[:, perm]
            a_all, b_all, cols, ch_all = a_all[perm], b_all[perm], cols[perm], ch_all[perm]
            segments = np.searchsorted(key[perm], _SEGMENT_KEYS)
        else:
            a_all = b_all = np.zeros(0)
            C_all = np.zeros((N_INPUTS, 0))
            cols = ch_all = np.zeros(0, dtype=np.int64)
            segments = np.zeros(N_INPUTS + 2, dtype=np.int64)
        if dense:
            Ad = np.ascontiguousarray(scipy.linalg.block_diag(*[d[0] for d in dense]))
            Bd = np.vstack([d[1] for d in dense])
            Cc = np.hstack([C_all] + [d[2] for d in dense])
            ch_all = np.concatenate([ch_all] + [np.full(d[0].shape[0], d[3], dtype=np.int64) for d in dense])
        else:
            Ad, Bd, Cc = np.zeros((0, 0)), np.zeros((0, nw)), C_all
        return DiscreteController(ad=a_all, bd=b_all, state_input=cols, Ad=Ad, Bd=Bd,
                                  Cc=np.ascontiguousarray(Cc), Dc=np.ascontiguousarray(self.D),
                                  state_channel=ch_all, segments=segments, dt=dt)

    def closed_loop_matrix(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """State matrix of the loop with the linearised plant ``dx' = A dx + B du`` (w = dx).

        A non-minimal controller is first reduced with python-control's ``minreal`` (SLICOT
        TB01PD), so that modes the loop can neither excite nor see (e.g. the LADR's structural
        zero eigenvalues) do not decide stability.
        """
        return loop_state_matrix(A, B, *self.minimal_realisation())

    def minimal_realisation(self) -> tuple:
        """``(A, B, C, D)``, reduced first by python-control's ``minreal`` (SLICOT TB01PD) unless
        the controller is minimal (C-contiguous arrays; reduced once per controller and kept on
        it: the stability check and the linearised integrator both read it, and the arrays are
        not to be written)."""
        Ac, Bc, Cc, Dc = self.A, self.B, self.C, self.D
        if not self.minimal and Ac.shape[0]:
            cached = self.__dict__.get("_minimal_realisation")
            if cached is not None:
                return cached
            import control

            red = control.ss(Ac, Bc, Cc, Dc).minreal()
            Ac, Bc, Cc = (np.ascontiguousarray(red.A), np.ascontiguousarray(red.B), np.ascontiguousarray(red.C))
            object.__setattr__(self, "_minimal_realisation", (Ac, Bc, Cc, Dc))
        return Ac, Bc, Cc, Dc


def loop_state_matrix(A: np.ndarray, B: np.ndarray, Ac: np.ndarray, Bc: np.ndarray, Cc: np.ndarray,
                      Dc: np.ndarray) -> np.ndarray:
    """State matrix ``[[A + B Dc, B Cc], [Bc, Ac]]`` of the linearised plant ``(A, B)`` (full state
    measured) in a loop with the controller ``(Ac, Bc, Cc, Dc)``; the controller's matrices may
    carry a leading axis of candidates (then one matrix per candidate, the products by numpy's
    stacked matmul)."""
    n, nc = A.shape[0], Ac.shape[-1]
    M = np.empty(Ac.shape[:-2] + (n + nc, n + nc))
    M[..., :n, :n] = A + B @ Dc
    M[..., :n, n:] = B @ Cc
    M[..., n:, :n] = Bc
    M[..., n:, n:] = Ac
    return M


@dataclasses.dataclass(frozen=True, eq=False)
class DiscreteController:
    """Sampled controller as the simulation kernel takes it.

    States ``[0, nd)`` are modal and single-input: ``z_i <- ad_i z_i + bd_i w[state_input[i]]``.
    ``segments`` (4,) orders them for the kernel: ``[segments[r], segments[r + 1])`` for pump
    ``r`` in 0..1 read signal ``r`` and drive pump ``r`` with weight 1 (their ``Cc`` column is
    the unit vector), then ``[segments[2], segments[3] = nd)`` hold the other modal states.
    The remaining states advance densely, ``z_d <- Ad z_d + Bd w``. The output is
    ``du = Cc z + Dc w``; ``state_channel`` names each state's pump (for anti-windup).
    """

    ad: np.ndarray
    bd: np.ndarray
    state_input: np.ndarray
    Ad: np.ndarray
    Bd: np.ndarray
    Cc: np.ndarray
    Dc: np.ndarray
    state_channel: np.ndarray
    segments: np.ndarray
    dt: float

    def __post_init__(self):
        # The kernel does no bounds checking: make inconsistent shapes fail here instead (the
        # segment contents are checked by check_segments, in the tests).
        nd, nq = self.ad.size, self.Ad.shape[0]
        seg = self.segments.tolist() if self.segments.shape == (4,) else None
        ok = (self.bd.shape == (nd,) and self.state_input.shape == (nd,)
              and self.Ad.shape == (nq, nq) and self.Bd.shape == (nq, 4)
              and self.Cc.shape == (2, nd + nq) and self.Dc.shape == (2, 4)
              and self.state_channel.shape == (nd + nq,)
              and seg is not None and 0 == seg[0] <= seg[1] <= seg[2] <= seg[3] == nd
              and (nd == 0 or 0 <= self.state_input.min() <= self.state_input.max() < 4))
        if not ok:
            raise ValueError("inconsistent DiscreteController shapes or segments")

    def check_segments(self) -> bool:
        """Whether the modal states follow ``segments`` (input 0 / pump 0 with unit weight,
        then input 1 / pump 1 with unit weight, then the rest)."""
        lo, mid, hi = self.segments[:3]
        return (bool(np.all(self.state_input[lo:mid] == 0)) and bool(np.all(self.state_input[mid:hi] == 1))
                and np.array_equal(self.Cc[:, lo:hi], _UNIT_ROWS[:, self.state_input[lo:hi]]))

    @property
    def n_states(self) -> int:
        return self.ad.size + self.Ad.shape[0]

    def step(self, z: np.ndarray, w: np.ndarray) -> np.ndarray:
        """One controller update in Python (reference for tests): returns ``z[k+1]``."""
        nd = self.ad.size
        return np.concatenate([self.ad * z[:nd] + self.bd * w[self.state_input], self.Ad @ z[nd:] + self.Bd @ w])


def lqr_gain(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """State-feedback gain ``K = R^-1 B^T P`` from the continuous algebraic Riccati equation.

    ``P`` comes from the ordered real Schur form of the Hamiltonian
    ``H = [[A, -B R^-1 B^T], [-Q, -A^T]]`` (Laub's method): with the stable invariant subspace
    spanned by ``[U11; U21]``, ``P = U21 U11^-1``. A solution whose Riccati residual exceeds
    ``RICCATI_RESIDUAL_TOL`` times the size of its terms (an ill-conditioned ``U11``) is
    rejected. For the 4-state QTP this is several times faster than
    ``scipy.linalg.solve_continuous_are`` (whose balancing and QZ steps matter for larger, badly
    scaled problems); the tests compare both, and python-control's ``lqr``. It runs as one
    compiled call (:func:`~heurtune.objectives.qtp.design_kernels.riccati_gain`, the arithmetic
    of the numpy code it replaced, within the rounding its conditioning allows).

    Parameters
    ----------
    A : ndarray (n, n)
    B : ndarray (n, m)
    Q : ndarray (n, n)
    R : ndarray (m, m)

    Returns
    -------
    ndarray (m, n)
        K.

    Raises
    ------
    ControllerDesignError
        With reason ``riccati_failed`` when there is no stabilising solution.
    """
    return _riccati_outcome(_design_kernels.riccati_gain, A, B, Q, R)


def _riccati_outcome(kernel, A: np.ndarray, B: np.ndarray, *weights) -> np.ndarray:
    """``kernel(A, B, *weights, ...)`` (:func:`~heurtune.objectives.qtp.design_kernels.riccati_gain`
    or its form of diagonal weights), its gain K, or its failure raised as ControllerDesignError."""
    n = A.shape[0]
    try:
        outcome, count, K = kernel(A, B, *weights, RICCATI_RESIDUAL_TOL, _design_kernels.SELECT_STABLE)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ControllerDesignError("riccati_failed", str(exc)) from None
    if outcome == _design_kernels.RICCATI_SCHUR_FAILED:
        raise ControllerDesignError("riccati_failed", f"ordered Schur form failed (LAPACK info {count})")
    if outcome == _design_kernels.RICCATI_STABLE_COUNT:
        raise ControllerDesignError("riccati_failed", f"{count} stable Hamiltonian eigenvalues, need {n}")
    if outcome == _design_kernels.RICCATI_RESIDUAL:
        # an ill-conditioned stable subspace shows as a poor Riccati residual
        raise ControllerDesignError("riccati_failed", "Riccati residual too large (ill-conditioned problem)")
    return K


def _weighted_lqr_gain(A: np.ndarray, B: np.ndarray, q: list, r: list) -> np.ndarray:
    """``lqr_gain(A, B, diag(q), diag(r))``, remembered for the last ``_LQR_CACHE_SIZE``
    weights (keyed by their exact bits and those of ``A`` and ``B``; the gain is read-only).

    A finite-difference gradient moves one tuning value at a time, and the moves of the
    integral gains and orders keep the weights: those designs reuse the Riccati solution. A
    failed design is remembered as its error and raised again.
    """
    weights = np.array([*q, *r], dtype=np.float64)  # diag(q), then diag(r), built in the kernel
    key = (A.shape, B.shape, A.tobytes(), B.tobytes(), weights.tobytes())
    hit = _lqr_cache.get(key)
    if hit is None:
        try:
            hit = _riccati_outcome(_design_kernels.weighted_riccati_gain, A, B, weights)
            hit.flags.writeable = False
        except ControllerDesignError as exc:
            hit = exc
        if len(_lqr_cache) >= _LQR_CACHE_SIZE:
            _lqr_cache.popitem(last=False)
        _lqr_cache[key] = hit
    if isinstance(hit, ControllerDesignError):
        raise ControllerDesignError(hit.reason, hit.detail)
    return hit


# Which error each pump integrates: "diagonal" (thesis eq. 3.9: pump r integrates e_r) or
# "anti-diagonal" (pump 1 integrates e2, pump 2 integrates e1).
PAIRINGS = ("diagonal", "anti-diagonal")
# What integral_action_obstruction can check (see there).
_INTEGRAL_CHECKS = ("signs", "det", None)

_LADR_BETAS = tuple(f"beta{i}{j}" for j in (1, 2, 3) for i in (1, 2, 3, 4))
LADR_NAMES = _LADR_BETAS + ("b1", "b2", "b3", "b4", "r1", "r2", "r3", "r4")


class PlantLinearisation(typing.NamedTuple):
    """The nominal plant's linearisation a structure designs on: ``dx' = A dx + B du``,
    measured outputs ``dy = C dx`` (the two lower levels)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray


def _error_of_pump(pairing: str, pump: int) -> int:
    """Index of the error (0: e1, 1: e2) that pump ``pump`` integrates under ``pairing``."""
    return pump if pairing == "diagonal" else 1 - pump


@functools.lru_cache(maxsize=4096)
def _integrator_modal(alpha: float, order: int, band: tuple, realisation: str):
    """``fractional_integrator(alpha, order, band, realisation).modal()``, kept for repeated
    orders (optimisers revisit the bounds of alpha, and a finite-difference gradient moves one
    variable at a time); the arrays are read-only."""
    modal = fractional_integrator(alpha, order, band, realisation).modal()
    if modal is not None:
        for arr in modal[:2]:
            arr.flags.writeable = False
    return modal


def folqi_design(values: dict, A, B, alphas, order, band, realisation, pairing="diagonal") -> LinearController:
    """FOLQI (IOLQI with ``alphas = (1, 1)``) of thesis eq. 3.9: ``du = -K dx + diag(Ki_r / s^alpha_r) e``
    with ``K`` from the Riccati equation of the weights and each pump integrating the error
    ``pairing`` gives it.

    Parameters
    ----------
    values : dict
        ``Q11..Q44``, ``R11``, ``R22``, ``Ki1``, ``Ki2`` (and ``alpha1``, ``alpha2`` when read).
    A, B : ndarray
        The plant linearisation.
    alphas : (float, float)
        The fractional orders (1, 1 for IOLQI).
    order : int
        Oustaloup's order.
    band : (float, float)
        Oustaloup's band in rad/s.
    realisation : {"direct", "integer_split"}
    pairing : {"diagonal", "anti-diagonal"}

    Returns
    -------
    LinearController

    Raises
    ------
    ControllerDesignError
    """
    K = _weighted_lqr_gain(A, B, [values["Q11"], values["Q22"], values["Q33"], values["Q44"]],
                           [values["R11"], values["R22"]])
    layout = _folqi_layout(tuple(float(a) for a in alphas), order, tuple(band), realisation, pairing)
    (c1, d1, err1, _, _), (c2, d2, err2, _, _) = layout.outputs  # pump 1's states first
    Cc, Dc = _design_kernels.folqi_outputs(K, float(values["Ki1"]), c1, d1, err1, float(values["Ki2"]), c2, d2, err2)
    modal = None
    if layout.modal_inputs is not None:
        # Partial fractions are the modal form already: each block is diagonal and reads one
        # error (what modal_blocks would derive from the matrices, taken from them as it would).
        (p1, b1, e1, n1), (p2, b2, e2, _) = layout.modal_inputs
        modal = (("modal", p1, b1, Cc[:, :n1], e1, 0), ("modal", p2, b2, Cc[:, n1:], e2, 1))
    return LinearController(layout.A, layout.B, Cc, Dc, layout.blocks, (0, 1), modal=modal,
                            modal_arrays=layout.modal_arrays)


class _FolqiLayout(typing.NamedTuple):
    """What a FOLQI's controller matrices take from its orders alone (:func:`_folqi_layout`);
    the arrays are read-only."""

    A: np.ndarray  # (nz, nz) block diagonal: the integrators' state matrices
    B: np.ndarray  # (nz, 4) each block reads its error
    blocks: tuple  # (start, stop) per pump
    outputs: tuple  # per pump: (output row of the block, direct term, error read, start, stop)
    # per pump, when both blocks are modal (else None): its poles, the weights its states read
    # their error with (a view of B), that error, and where pump 2's states start
    modal_inputs: tuple | None
    modal_arrays: tuple | None  # LinearController.modal_arrays when both blocks are modal


@functools.lru_cache(maxsize=1024)
def _folqi_layout(alphas: tuple, order: int, band: tuple, realisation: str, pairing: str) -> _FolqiLayout:
    """The part of :func:`folqi_design` that depends on the orders alone, kept for repeated
    orders (a finite-difference gradient moves one tuning value at a time)."""
    modal_parts = [_integrator_modal(a, order, band, realisation) for a in alphas]
    errs = [_error_of_pump(pairing, ch) for ch in range(len(alphas))]
    if all(m is not None for m in modal_parts):
        # diagonal form (the discretisation needs no eigen-decomposition): A is the poles,
        # each state reads its error with weight 1, and the output weights are the residues
        (p1, c1, d1), (p2, c2, d2) = modal_parts
        Ac, Bc, lam, b, col, channel = _design_kernels.modal_layout(p1, p2, errs[0], errs[1])
        n1, nz = p1.size, lam.size
        # The modal arrays stay writeable (the simulation kernels' types; nothing writes them):
        # every controller of this layout shares them.
        modal_arrays = (lam, b, col, channel)
        for arr in (Ac, Bc):
            arr.flags.writeable = False
        modal_inputs = ((p1, Bc[:n1, errs[0]], errs[0], n1), (p2, Bc[n1:, errs[1]], errs[1], n1))
        return _FolqiLayout(Ac, Bc, ((0, n1), (n1, nz)), ((c1, d1, errs[0], 0, n1), (c2, d2, errs[1], n1, nz)),
                            modal_inputs, modal_arrays)
    parts = [fractional_integrator(a, order, band, realisation).state_space() if m is None
             else (np.diag(m[0]), np.ones(m[0].size), m[1], m[2]) for a, m in zip(alphas, modal_parts)]
    sizes = [p[0].shape[0] for p in parts]
    Ac = np.zeros((sum(sizes), sum(sizes)))
    Bc = np.zeros((Ac.shape[0], N_MEASURED))
    blocks, outputs = [], []
    start = 0
    for (Af, bf, cf, df), size, err in zip(parts, sizes, errs):
        stop = start + size
        Ac[start:stop, start:stop] = Af
        Bc[start:stop, err] = -bf  # e_err = -w_err
        blocks.append((start, stop))
        outputs.append((cf, df, err, start, stop))
        start = stop
    for arr in (Ac, Bc):
        arr.flags.writeable = False
    return _FolqiLayout(Ac, Bc, tuple(blocks), tuple(outputs), None, None)


def ladr_design(values: dict, pairing: str = "diagonal") -> LinearController:
    """LADR of the thesis Appendix A (eq. A.1-A.22), implemented as printed.

    Channel 1 (pump 1) observes tanks 1 and 4 with states (Z1, Z4, Z5, Z7); channel 2 observes
    tanks 2 and 3 with (Z2, Z3, Z6, Z8). Printed quirks kept as written: A.4 has ``+ b4 u1`` in
    the extended state Z5 while A.9 has no input term; A.5 uses ``beta12`` (``beta42`` is never
    used); A.18/A.21 add two gains on the same error. With a zero set-point (``x_id = 0``) the
    tracking-differentiator states Z11..Z14 stay at zero, so they are left out of the
    realisation and ``r1..r4`` have no effect on the regulator. As printed, the observer has
    structural zero eigenvalues (``Z1 - Z4`` and ``Z2 - Z3`` are never fed back, ``beta32 Z6 -
    beta22 Z8`` never changes), so the realisation is marked non-minimal for the stability check.

    With ``pairing = "anti-diagonal"`` each channel regulates the other lower tank: channel 1
    observes tanks 2 and 4 (pump 1 reaches tank 2 through tank 4), channel 2 tanks 1 and 3; the
    gains keep their printed slots.

    Parameters
    ----------
    values : dict
        The gains of Appendix A (``beta..``, ``b1..b4``, ``r1..r4``).
    pairing : {"diagonal", "anti-diagonal"}

    Returns
    -------
    LinearController
    """
    b = [values[f"b{i}"] for i in (1, 2, 3, 4)]
    if min(b) <= 0.0:
        raise ControllerDesignError("invalid_controller", "LADR needs b1..b4 > 0 (u = ... - Z/b)")
    beta = {name: values[name] for name in _LADR_BETAS}
    # channel: (pump, measured pair, observer gains, b pair, feedback gain, extended-state terms)
    channels = [
        dict(ch=0, meas=(_error_of_pump(pairing, 0), 3), l=(beta["beta11"], beta["beta41"]), bb=(b[0], b[3]),
             kp=beta["beta13"] + beta["beta43"],
             ext=((-beta["beta12"], b[3]), (-beta["beta12"], 0.0))),
        dict(ch=1, meas=(_error_of_pump(pairing, 1), 2), l=(beta["beta21"], beta["beta31"]), bb=(b[1], b[2]),
             kp=beta["beta23"] + beta["beta33"],
             ext=((-beta["beta22"], 0.0), (-beta["beta32"], 0.0))),
    ]
    nz = 8
    Ac = np.zeros((nz, nz))
    Bc = np.zeros((nz, N_MEASURED))
    Cc = np.zeros((N_INPUTS, nz))
    Dc = np.zeros((N_INPUTS, N_MEASURED))
    blocks = []
    for c in channels:
        s = 4 * c["ch"]  # local states: [Zp, Zq, Ep, Eq] (observer pair and extended states)
        ip, iq, ep, eq = s, s + 1, s + 2, s + 3
        # u = kp (0 - Zp - Zq) - Ep / bp - Eq / bq
        cu = np.zeros(nz)
        cu[ip] = cu[iq] = -c["kp"]
        cu[ep] = -1.0 / c["bb"][0]
        cu[eq] = -1.0 / c["bb"][1]
        Cc[c["ch"]] = cu
        # observer error e = Zp + Zq - x_p - x_q
        ce = np.zeros(nz)
        ce[ip] = ce[iq] = 1.0
        de = np.zeros(N_MEASURED)
        de[list(c["meas"])] = -1.0
        for row, ext, gain, bu in ((ip, ep, c["l"][0], c["bb"][0]), (iq, eq, c["l"][1], c["bb"][1])):
            Ac[row, ext] += 1.0
            Ac[row] += -gain * ce + bu * cu
            Bc[row] += -gain * de
        for row, (ge, gu) in zip((ep, eq), c["ext"]):
            Ac[row] += ge * ce + gu * cu
            Bc[row] += ge * de
        blocks.append((s, s + 4))
    return LinearController(Ac, Bc, Cc, Dc, tuple(blocks), (0, 1), minimal=False)


def lqi_design(values: dict, A, B) -> LinearController:
    """Textbook LQI: the integrated errors augment the plant state in the Riccati design.

    With ``xi' = e = r - y = -C x`` (regulation) the augmented plant is
    ``[x; xi]' = [[A, 0], [-C, 0]] [x; xi] + [B; 0] du`` with ``C = [I2 0]``; LQR with
    ``Q = diag(Q11..Q44, Qi1, Qi2)``, ``R = diag(R11, R22)`` gives ``du = -Kx x - Kxi xi``. The
    controller's states are the two exact integrators; their 2 x 2 output matrix is ``-Kxi``
    (both errors drive both pumps). For anti-windup, integrator j belongs to the pump it drives
    most strongly.

    Parameters
    ----------
    values : dict
        ``Q11..Q44``, ``Qi1``, ``Qi2``, ``R11``, ``R22``.
    A, B : ndarray
        The plant linearisation.

    Returns
    -------
    LinearController
    """
    n, m = A.shape[0], B.shape[1]
    Aa = np.zeros((n + m, n + m))
    Aa[:n, :n] = A
    Aa[n:, :n] = -np.eye(m, n)
    Ba = np.vstack([B, np.zeros((m, m))])
    Qa = np.diag([values[k] for k in ("Q11", "Q22", "Q33", "Q44", "Qi1", "Qi2")])
    R = np.diag([values["R11"], values["R22"]])
    Ka = lqr_gain(Aa, Ba, Qa, R)
    Kint = -Ka[:, n:]
    Bc = np.zeros((m, N_MEASURED))
    Bc[0, 0] = Bc[1, 1] = -1.0  # xi_j' = e_j = -w_j
    channel = tuple(int(np.argmax(np.abs(Kint[:, j]))) for j in range(m))
    return LinearController(np.zeros((m, m)), Bc, np.ascontiguousarray(Kint), -Ka[:, :n].copy(),
                            ((0, 1), (1, 2)), channel)


def dc_gain(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Steady-state gain ``G(0) = -C A^-1 B`` of a stable linear plant.

    Parameters
    ----------
    A, B, C : ndarray

    Returns
    -------
    ndarray
    """
    return -C @ np.linalg.solve(A, B)


def integral_action_obstruction(check, pairing: str, A, B, C, ki_bounds=((0.1, 10.0), (0.1, 10.0)),
                                 gain_sign: int = 1):
    """Why no controller of this structure can hold integral action on this plant, or None.

    For state feedback ``-K x`` that stabilises a stable plant, ``det(I + K (-A)^-1 B) > 0``, so
    the inner loop keeps the sign of ``det G(0)``. Integrators ``Kint / s`` on the errors then
    close a loop whose state matrix has determinant ``det(A - BK) det G(0) det(Kint)`` times a
    positive factor, and a Hurwitz matrix of even size has a positive determinant: the loop can
    be stable only if ``det G(0) det(Kint) > 0`` (derivation in docs/model.md). ``Kint`` is
    ``diag(Ki1, Ki2)`` (diagonal pairing) or ``[[0, Ki1], [Ki2, 0]]`` (anti-diagonal), so
    ``sign det(Kint) = +-sign(Ki1) sign(Ki2)``.

    Parameters
    ----------
    check : {"signs", "det", None} or str
        What the structure's integral action needs (its ``extras["integral_check"]``; a
        registered controller type stands for the check it declares):
        ``"signs"`` integrators ``Ki_r / s`` on paired errors (FOLQI, IOLQI, PID), ``"det"`` a
        full integral gain that only needs ``det G(0) != 0`` (LQI), None no check (LADR, whose
        extended-state observer is not an integrator on the errors).
    pairing : {"diagonal", "anti-diagonal"}
    A, B, C : ndarray
        Linearised plant.
    ki_bounds : pair of (low, high)
        Bounds of Ki1 and Ki2: the signs they allow.
    gain_sign : {1, -1}
        The sign of the determinant of a static gain between the integrators and the pumps
        (a PID's decoupler), 1 when there is none.

    Returns
    -------
    str or None
        A one-line explanation naming the fix, or None when the structure can work.
    """
    if check not in _INTEGRAL_CHECKS:  # a controller type: the check it declares
        structure = get_structure("qtp", check)
        check = structure.extras.get("integral_check", "signs" if structure.paired else None)
    if check is None:
        return None
    G0 = dc_gain(A, B, C)
    det = float(np.linalg.det(G0))
    scale = float(np.abs(G0).max()) ** 2
    if abs(det) <= 1e-9 * scale:
        return (f"det G(0) = {det:.3g}: the plant has a transmission zero at s = 0, so no controller "
                "can hold integral action on both outputs; change the valve splits (gamma1 + gamma2 != 1)")
    if check == "det":
        return None
    signs = [{s for s, ok in ((1, hi > 0), (-1, lo < 0)) if ok} for lo, hi in ki_bounds]
    flip = (1 if pairing == "diagonal" else -1) * (1 if gain_sign > 0 else -1)
    possible = {flip * a * b for a in signs[0] for b in signs[1]}
    needed = 1 if det > 0 else -1
    if needed in possible:
        return None
    other = "anti-diagonal" if pairing == "diagonal" else "diagonal"
    return (f"det G(0) = {det:.3g} and {pairing} integral action with Ki1, Ki2 in their bounds has "
            f"det(Kint) of sign {-needed:+d}: every such loop with exact integral action has a real "
            f"right-half-plane pole (see docs/model.md); use [controller] pairing = \"{other}\" "
            "or type = \"lqi\"")
