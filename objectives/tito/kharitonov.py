"""MIMO Kharitonov robust-stability test of a 2x2 decentralised loop (paper 000, sec. IV-A, eq. 27-37, 59-70).

Paper 000 checks its decoupled, decentralised PID loops with the Kharitonov theorem applied to the
characteristic polynomial of the MIMO closed loop ``det[I + C(s) A(s)] = 0`` (eq. 28, 65), its
delays replaced by the first-order Taylor term ``e^{-Ls} ~ 1 - Ls`` (eq. 62). This module builds
that polynomial exactly (``numpy.polymul`` / ``numpy.polyadd``) for any 2x2 matrix of rational
transfer functions with delays and a diagonal PI/PID controller, bounds its coefficients over a
box of plant parameters, and runs the four Kharitonov polynomials through the Hurwitz test,
with the Hurwitz matrix and the paper's "row-reduced" Hurwitz matrix (Tables 4-6).
The SISO tools are reused from :mod:`heurtune.objectives.robustness` (:func:`hurwitz_matrix`,
:func:`hurwitz_determinants`, :func:`kharitonov_polynomials`, :func:`pade`,
:func:`interval_characteristic_polynomial`).

Which polynomial, which roots
    Every element ``a_ij`` is a sum of terms ``num/den e^{-L s}`` (:class:`DelayTerm`;
    a :class:`~heurtune.objectives.tito.model.TFElement` or ``FOPDT`` is one term, a number a
    constant). Each delay is replaced by ``P_n(s)/P_d(s)`` (``1 - L s`` over 1, or a Pade
    approximant), so ``a_ij = n_ij / d_ij`` with ``d_ij`` the *product* of its terms'
    denominators, and ``c_i = n_ci / d_ci``. The returned polynomial is::

        N(s) = (d_c1 d11 + n_c1 n11)(d_c2 d22 + n_c2 n22) d12 d21 - n_c1 n_c2 n12 n21 d11 d22
             = det[I + C(s) A(s)] * d_c1 d_c2 d11 d12 d21 d22

    No common factor is cancelled (no polynomial GCD is taken, so nothing depends on a rounding
    threshold). Its roots are therefore exactly the closed-loop poles of the loop in which every
    term of every element (with its delay approximant) and every controller is realised as a block
    of its own (a minimal realisation of each block, assumed coprime): the poles of ``det[I + CA]``
    plus the fixed modes of that interconnection, e.g. a lag shared by two elements appears twice,
    the pole of an element that no loop sees stays. Those fixed modes are open-loop poles of
    stable blocks here, so they do not change a stability verdict, but they do raise the degree.
    For a PI/PID controller with ``Ki = 0`` the common factor ``s`` is removed, so that a P/PD
    controller adds no integrator.

Conventions
    Coefficients highest power first (``numpy.roots``), as in :mod:`heurtune.objectives.robustness`.
    The Kharitonov polynomials are returned in that module's order K1..K4 (in increasing powers
    ``l l u u``, ``u u l l``, ``l u u l``, ``u l l u``); paper 000 numbers them K1, K3, K4, K2.

The paper's own numbers (:func:`paper000_qts_chain`)
    Eq. 66 does not follow from eqs. 62-63. It is reproduced, to every printed digit, from the
    diagonal entries *as printed in eq. 64* (whose ``s`` terms have the wrong sign, and whose
    loop-2 entry uses ``2.119 * 0.061 = 0.129`` of eq. 59 instead of eq. 62's 0.3), as the
    magnitudes of the coefficients with their powers of ten and their minus signs dropped:
    ``-859245.8 s^6 - 5896514 s^5 - 10194530 s^4 - 408507.1 s^3 - 485.82 s^2 - 129.86 s + 0.342075``.
    The printed K1..K4 (eq. 67-70) cannot be Kharitonov polynomials of any coefficient box (four
    different ``s`` coefficients, three ``s^3`` and ``s^5`` values, a 3-1 split of ``s^2``, see
    :func:`kharitonov_pattern_mismatches`), are monic with constants 205-307 while eq. 66 is not
    monic and has a constant 0.34, and none of them is Hurwitz (each has a complex pair in the
    right half-plane). See ``tests/objectives/tito/test_kharitonov_mimo.py`` for the numbers.

The paper's controllers (eq. 48, 53, 58; :data:`PAPER000_PID`)
    With the delays exact (Pade(10), converged in the order), they are stable on the printed FOPDT
    loops (eq. 46-47, 51-52, 56-57; largest real parts QTS -0.0102 / -0.0081, CCTS -0.0397 /
    -0.0786, CSTS -0.0072 / -0.0116), but on the printed plants (eq. 44, 49, 54) with the inverted
    decoupler the QTS loops have poles at ``0.3468 +- 0.4933j`` and ``0.2745 +- 0.3998j`` and the
    CCTS loops at ``0.0301 +- 0.1443j`` and ``0.0124 +- 0.1150j`` (roots of the exact loops too);
    the CSTS loops are stable (-0.00025).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from collections.abc import Mapping, Sequence

import numpy as np

from heurtune.core.errors import ConfigError
from heurtune.objectives.robustness import (
    hurwitz_determinants,
    hurwitz_matrix,
    interval_characteristic_polynomial,
    kharitonov_polynomials,
    pade,
)

from .model import FOPDT, Decoupler, ParallelPID, PIController, PIDController, TFElement, TITOPlant

__all__ = [
    "DELTA_KINDS",
    "PAPER000_EQ66",
    "PAPER000_EQ67_70",
    "PAPER000_FOPDT",
    "PAPER000_PID",
    "DelayTerm",
    "MimoKharitonovResult",
    "characteristic_polynomial",
    "closed_loop_poles",
    "decoupled_elements",
    "delay_approximation",
    "interval_characteristic_bounds",
    "kharitonov_hurwitz",
    "kharitonov_pattern_mismatches",
    "loop_polynomial",
    "mimo_kharitonov_test",
    "paper000_qts_chain",
    "parameter_box",
    "perturbed_plant",
    "row_reduce",
    "row_reduced_hurwitz",
]

DELTA_KINDS = ("K", "T", "L")
"""Parameter kinds of a box: static gains, time constants (lags and leads), dead times."""

def _printed(table: str):
    from heurtune.objectives.tito.papers.printed import printed_table

    return printed_table("000", table)


def _printed_polynomials() -> dict:
    t = _printed("polynomials")
    return {str(r["name"]): np.array([float(r[f"s{k}"]) for k in range(6, -1, -1)]) for _, r in t.iterrows()}


_POLYS = _printed_polynomials()
PAPER000_EQ66 = _POLYS["characteristic"]
"""Paper 000 eq. 66 as printed (QTS characteristic polynomial, highest power first), from
``experiments/printed/paper_000/polynomials.csv``."""

PAPER000_EQ67_70 = tuple(_POLYS[f"K{k}"] for k in range(1, 5))
"""Paper 000 eq. 67-70, its K1..K4 as printed (highest power first), from the same file."""


def _first_per_loop(table: str, plant: str, columns) -> tuple:
    t = _printed(table)
    t = t[t["plant"] == plant].groupby("loop", sort=True).head(1)
    return tuple(tuple(float(r[c]) for c in columns) for _, r in t.iterrows())


PAPER000_FOPDT = {p: _first_per_loop("fopdt", p, ("K", "T", "L")) for p in ("qts", "ccts", "csts")}
"""Paper 000's printed FOPDT models of the decoupled loops (eqs. 46-47, 51-52, 56-57), ``(K, T, L)``
per loop, from ``fopdt.csv``."""

PAPER000_PID = {p: _first_per_loop("controllers", p, ("Kp", "Ki", "Kd")) for p in ("qts", "ccts", "csts")}
"""Paper 000's proposed controllers ``Kp + Ki/s + Kd s`` (no filter; eqs. 48, 53, 58; eq. 60 prints
the QTS's Ki1 as 0.2985), ``(Kp, Ki, Kd)`` per loop, from ``controllers.csv``."""


# ----------------------------------------------------------------------------------------------
# Polynomial helpers
# ----------------------------------------------------------------------------------------------


def _trim(p) -> np.ndarray:
    p = np.atleast_1d(np.asarray(p, dtype=float))
    nz = np.flatnonzero(p)
    return p[nz[0]:].copy() if nz.size else np.zeros(1)


def _mul(*ps) -> np.ndarray:
    """Product of polynomials: ``numpy.polymul`` is ``numpy.convolve`` of the coefficient arrays."""
    out = np.ones(1)
    for p in ps:
        out = np.convolve(out, np.asarray(p, dtype=float))
    return _trim(out)


def _add(*ps) -> np.ndarray:
    out = np.zeros(1)
    for p in ps:
        out = np.polyadd(out, p)
    return _trim(out)


def _times(times) -> np.ndarray:
    """``prod(1 + s t)`` over the time constants (a zero time constant gives 1)."""
    return _mul(*([t, 1.0] for t in times))


def _real_poly(p, name: str) -> np.ndarray:
    try:
        a = np.atleast_1d(np.asarray(p, dtype=float))
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be an array of real coefficients, got {p!r}") from None
    if a.ndim != 1 or a.size == 0 or not np.all(np.isfinite(a)):
        raise ConfigError(f"{name} must be a non-empty 1-D array of finite coefficients, got {p!r}")
    return _trim(a)


def _number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


# ----------------------------------------------------------------------------------------------
# Elements, controllers, delays
# ----------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class DelayTerm:
    """One term ``num(s)/den(s) e^{-L s}`` of a plant element.

    Parameters
    ----------
    num, den : sequence of float
        Coefficients, highest power first; ``den`` must not be the zero polynomial.
    L : float
        Dead time, finite and ``>= 0``.
    """

    num: tuple
    den: tuple
    L: float = 0.0

    def __post_init__(self):
        num = _real_poly(self.num, "DelayTerm.num")
        den = _real_poly(self.den, "DelayTerm.den")
        if not np.any(den):
            raise ConfigError("DelayTerm.den must not be the zero polynomial")
        if not (_number(self.L) and math.isfinite(self.L) and self.L >= 0):
            raise ConfigError(f"DelayTerm.L must be a finite number >= 0, got {self.L!r}")
        object.__setattr__(self, "num", tuple(float(v) for v in num))
        object.__setattr__(self, "den", tuple(float(v) for v in den))
        object.__setattr__(self, "L", float(self.L))


def _element_terms(x, name: str) -> tuple[DelayTerm, ...]:
    """An element as a sum of :class:`DelayTerm` (an empty tuple is the zero element)."""
    if isinstance(x, DelayTerm):
        return (x,)
    if isinstance(x, TFElement):
        return (DelayTerm(x.K * _times(x.leads), _times(x.lags), x.L),)
    if isinstance(x, FOPDT):
        return (DelayTerm([x.K], _times([x.T]), x.L),)
    if _number(x):
        if not math.isfinite(x):
            raise ConfigError(f"{name} must be finite, got {x!r}")
        return () if x == 0 else (DelayTerm([float(x)], [1.0], 0.0),)
    if isinstance(x, (list, tuple)):
        return tuple(t for k, item in enumerate(x) for t in _element_terms(item, f"{name}[{k}]"))
    raise ConfigError(
        f"{name} must be a TFElement, FOPDT, DelayTerm, number or a list of them (a sum), got {type(x).__name__}"
    )


def _matrix(A, name: str = "A") -> list[list[tuple[DelayTerm, ...]]]:
    """2x2 nested list of term tuples from a TITOPlant, Decoupler or 2x2 sequence."""
    if isinstance(A, TITOPlant):
        rows = [[A.g11, A.g12], [A.g21, A.g22]]
    elif isinstance(A, Decoupler):
        rows = decoupled_elements(A)
    else:
        if isinstance(A, np.ndarray):
            A = A.tolist()
        if not (isinstance(A, (list, tuple)) and len(A) == 2
                and all(isinstance(r, (list, tuple)) and len(r) == 2 for r in A)):
            raise ConfigError(f"{name} must be a TITOPlant, a Decoupler or a 2x2 nested sequence of elements")
        rows = A
    return [[_element_terms(rows[i][j], f"{name}[{i}][{j}]") for j in range(2)] for i in range(2)]


def decoupled_elements(decoupler: Decoupler) -> list[list]:
    """The decoupled plant ``G D = diag(h11, h22)`` as element sums, for :func:`characteristic_polynomial`.

    Case 1: ``h11 = (g11 - g12 g21 / g22) p1``, ``h22 = (g22 - g12 g21 / g11) p2``; case 2:
    ``h11 = (g12 - g11 g22 / g21) p3``, ``h22 = (g21 - g22 g11 / g12) p4`` (see
    :class:`~heurtune.objectives.tito.model.Decoupler`). Each ratio product is one
    :class:`DelayTerm` with the net delay of its factors plus the column delay. The off-diagonal
    elements of ``G D`` vanish identically and are returned as the number 0.

    Parameters
    ----------
    decoupler : Decoupler
        From :func:`~heurtune.objectives.tito.model.inverted_decoupler`.

    Returns
    -------
    list of list
        ``[[h11_terms, 0.0], [0.0, h22_terms]]``, ``h_terms`` a tuple of two :class:`DelayTerm`.
    """
    if not isinstance(decoupler, Decoupler):
        raise ConfigError(f"decoupler must be a Decoupler, got {type(decoupler).__name__}")
    p = decoupler.plant

    def single(e: TFElement, c: float) -> DelayTerm:
        return DelayTerm(e.K * _times(e.leads), _times(e.lags), e.L + c)

    def ratio(a: TFElement, b: TFElement, d: TFElement, c: float) -> DelayTerm:
        # -a b / d
        num = _mul([-a.K * b.K / d.K], _times(a.leads), _times(b.leads), _times(d.lags))
        den = _mul(_times(a.lags), _times(b.lags), _times(d.leads))
        return DelayTerm(num, den, a.L + b.L - d.L + c)

    c1, c2 = decoupler.column_delays
    if decoupler.case == 1:
        h11 = (single(p.g11, c1), ratio(p.g12, p.g21, p.g22, c1))
        h22 = (single(p.g22, c2), ratio(p.g12, p.g21, p.g11, c2))
    else:
        h11 = (single(p.g12, c1), ratio(p.g11, p.g22, p.g21, c1))
        h22 = (single(p.g21, c2), ratio(p.g22, p.g11, p.g12, c2))
    return [[h11, 0.0], [0.0, h22]]


def _controller(c, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(num, den)`` of one controller."""
    if isinstance(c, DelayTerm):
        if c.L != 0:
            raise ConfigError(f"{name}: a controller term must have L = 0, got {c.L!r}")
        return _trim(c.num), _trim(c.den)
    if isinstance(c, ParallelPID):
        Kp, Ki, Kd, Tf = c.Kp, c.Ki, c.Kd, c.Tf
    elif isinstance(c, PIDController):
        (Kp, Ki, Kd), Tf = c.parallel(), c.Tf
    elif isinstance(c, PIController):
        (Kp, Ki, Kd), Tf = c.parallel(), 0.0
    elif isinstance(c, (list, tuple)) and 2 <= len(c) <= 4 and all(_number(v) for v in c):
        Kp, Ki, Kd, Tf = (tuple(c) + (0.0, 0.0))[:4]
    else:
        raise ConfigError(f"{name} must be a ParallelPID, PIController, PIDController, a DelayTerm with L = 0 "
                          f"or a tuple (Kp, Ki[, Kd[, Tf]]), got {c!r}")
    vals = [float(v) for v in (Kp, Ki, Kd, Tf)]
    if not all(math.isfinite(v) for v in vals):
        raise ConfigError(f"{name}: gains and Tf must be finite, got (Kp, Ki, Kd, Tf) = {tuple(vals)}")
    Kp, Ki, Kd, Tf = vals
    if Tf < 0:
        raise ConfigError(f"{name}: the filter time Tf must be >= 0, got {Tf!r}")
    if Ki == 0:  # no integrator: cancel the common factor s of (Kd s^2 + Kp s) / (s (Tf s + 1))
        return _trim([Kd, Kp]), _trim([Tf, 1.0])
    return _trim([Kd, Kp, Ki]), _trim([Tf, 1.0, 0.0])


def _controllers(controllers) -> list[tuple[np.ndarray, np.ndarray]]:
    if isinstance(controllers, (str, bytes)) or not isinstance(controllers, Sequence) or len(controllers) != 2:
        raise ConfigError(f"controllers must be a pair (c1, c2), got {controllers!r}")
    return [_controller(c, f"controllers[{k}]") for k, c in enumerate(controllers)]


def delay_approximation(L: float, delay: str = "taylor", pade_order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Rational stand-in ``P_n(s) / P_d(s)`` for ``e^{-L s}``.

    Parameters
    ----------
    L : float
        Dead time, ``>= 0``.
    delay : {"taylor", "pade"}
        ``"taylor"``: the paper's first-order Taylor term ``1 - L s`` (over 1). ``"pade"``: the
        diagonal Pade approximant of :func:`heurtune.objectives.robustness.pade`.
    pade_order : int
        Order of the Pade approximant (``>= 1``); ignored for ``"taylor"``.

    Returns
    -------
    num, den : numpy.ndarray
        Highest power first; ``([1.], [1.])`` for ``L = 0``.
    """
    if not (_number(L) and math.isfinite(L) and L >= 0):
        raise ConfigError(f"L must be a finite number >= 0, got {L!r}")
    if delay == "taylor":
        return (np.array([-float(L), 1.0]), np.ones(1)) if L > 0 else (np.ones(1), np.ones(1))
    if delay == "pade":
        if isinstance(pade_order, bool) or not isinstance(pade_order, (int, np.integer)) or pade_order < 1:
            raise ConfigError(f"pade_order must be an integer >= 1, got {pade_order!r}")
        return pade(float(L), int(pade_order))
    raise ConfigError(f"delay must be 'taylor' or 'pade', got {delay!r}")


@functools.lru_cache(maxsize=4096)
def _delay_cached(L: float, delay: str, pade_order: int) -> tuple[np.ndarray, np.ndarray]:
    pn, pd = delay_approximation(L, delay, pade_order)
    pn.setflags(write=False)
    pd.setflags(write=False)
    return pn, pd


def _element_poly(terms: tuple[DelayTerm, ...], delay: str, pade_order: int) -> tuple[np.ndarray, np.ndarray]:
    """``(n, d)`` of a sum of terms over the product of the term denominators."""
    if not terms:
        return np.zeros(1), np.ones(1)
    nums, dens = [], []
    for t in terms:
        pn, pd = _delay_cached(t.L, delay, pade_order)
        nums.append(_mul(t.num, pn))
        dens.append(_mul(t.den, pd))
    n = _add(*(_mul(nums[k], *(dens[j] for j in range(len(terms)) if j != k)) for k in range(len(terms))))
    return n, _mul(*dens)


# ----------------------------------------------------------------------------------------------
# Characteristic polynomial
# ----------------------------------------------------------------------------------------------


def loop_polynomial(element, controller, *, delay: str = "taylor", pade_order: int = 2) -> np.ndarray:
    """Characteristic polynomial ``d_c d + n_c n`` of the SISO loop ``1 + c(s) g(s) = 0``.

    Parameters
    ----------
    element : TFElement, FOPDT, DelayTerm, number or list of them
        The plant ``g`` (a list is a sum).
    controller : ParallelPID, PIController, PIDController, DelayTerm or tuple
        ``(Kp, Ki[, Kd[, Tf]])`` is ``(Kp + Ki/s + Kd s) / (1 + Tf s)``.
    delay, pade_order
        See :func:`delay_approximation`.

    Returns
    -------
    numpy.ndarray
        Highest power first; no common factor cancelled (see the module notes).
    """
    n, d = _element_poly(_element_terms(element, "element"), delay, pade_order)
    nc, dc = _controller(controller, "controller")
    return _add(_mul(dc, d), _mul(nc, n))


def characteristic_polynomial(A, controllers, *, delay: str = "taylor", pade_order: int = 2) -> np.ndarray:
    """Numerator of ``det[I + C(s) A(s)]`` over the product of all denominators (paper 000 eq. 28, 65-66).

    With ``C = diag(c1, c2)``, ``c_i = n_ci/d_ci`` and ``a_ij = n_ij/d_ij``::

        N = (d_c1 d11 + n_c1 n11)(d_c2 d22 + n_c2 n22) d12 d21 - n_c1 n_c2 n12 n21 d11 d22

    Its roots are the closed-loop poles of the rational approximation in which every term of every
    element and every controller is its own block (module notes); ``det(I + C A) = det(I + A C)``
    (Sylvester), so it does not matter on which side the controller is written. For a decoupled
    (diagonal) ``A`` it is the product of the two :func:`loop_polynomial`.

    Parameters
    ----------
    A : TITOPlant, Decoupler or 2x2 nested sequence
        The plant the controllers see: a :class:`TITOPlant` (no decoupler), a :class:`Decoupler`
        (its decoupled ``G D`` from :func:`decoupled_elements`), or ``[[a11, a12], [a21, a22]]`` of
        TFElement / FOPDT / DelayTerm / numbers / lists of them (sums), e.g. the FOPDT diagonal
        model ``[[FOPDT(..), 0], [0, FOPDT(..)]]``.
    controllers : pair
        ``(c1, c2)``, each a ParallelPID (its ``Tf`` filters the whole controller), PIController,
        PIDController (filter ``Tf``), a tuple ``(Kp, Ki[, Kd[, Tf]])`` or a DelayTerm with ``L = 0``.
    delay : {"taylor", "pade"}
        How each ``e^{-L s}`` is replaced: ``1 - L s`` (the paper's) or a Pade approximant.
    pade_order : int
        Order of the Pade approximant.

    Returns
    -------
    numpy.ndarray
        Coefficients, highest power first (not normalised: the sign and scale are those of the
        formula above).

    Notes
    -----
    The Taylor term is a poor stand-in with derivative action: for a loop ``K e^{-Ls}/(Ts+1)`` with
    the PID ``(Kd s^2 + Kp s + Ki)/(s (Tf s + 1))``, ``d_c d + n_c n`` has the leading coefficient
    ``T Tf - Kd K L`` and the constant ``Ki K``; whenever ``Kd K L > T Tf`` (always for an unfiltered
    PID, ``Tf = 0``) the signs differ and the polynomial has a spurious right-half-plane root (paper
    000's QTS loop 1 with Taylor: ``s = 80.19``, stable with Pade). Use ``delay="pade"`` there.
    """
    terms = _matrix(A)
    nds = [[_element_poly(terms[i][j], delay, pade_order) for j in range(2)] for i in range(2)]
    return _assemble(nds, _controllers(controllers))


def _assemble(nds, ctrl) -> np.ndarray:
    """``N`` from the element pairs ``nds[i][j] = (n_ij, d_ij)`` and the controller pairs."""
    (nc1, dc1), (nc2, dc2) = ctrl
    (n11, d11), (n12, d12) = nds[0]
    (n21, d21), (n22, d22) = nds[1]
    b1 = _add(_mul(dc1, d11), _mul(nc1, n11))
    b2 = _add(_mul(dc2, d22), _mul(nc2, n22))
    return _add(_mul(b1, b2, d12, d21), -_mul(nc1, nc2, n12, n21, d11, d22))


def closed_loop_poles(A, controllers, *, delay: str = "pade", pade_order: int = 10) -> np.ndarray:
    """Roots of :func:`characteristic_polynomial` (default: Pade(10) delays), sorted by real part.

    Parameters
    ----------
    A, controllers, delay, pade_order
        See :func:`characteristic_polynomial`.

    Returns
    -------
    numpy.ndarray
        Complex roots, largest real part last.
    """
    r = np.roots(characteristic_polynomial(A, controllers, delay=delay, pade_order=pade_order))
    return r[np.argsort(r.real, kind="stable")]


# ----------------------------------------------------------------------------------------------
# Parameter box and interval polynomial
# ----------------------------------------------------------------------------------------------


def _deltas(delta) -> dict:
    if _number(delta):
        if not (math.isfinite(delta) and 0 < delta < 1):
            raise ConfigError(f"delta must be a number in (0, 1), got {delta!r}")
        return dict.fromkeys(DELTA_KINDS, float(delta))
    if isinstance(delta, Mapping):
        unknown = sorted(set(delta) - set(DELTA_KINDS))
        if unknown:
            raise ConfigError(f"delta: unknown kind(s) {', '.join(map(str, unknown))}; allowed: "
                              f"{', '.join(DELTA_KINDS)}")
        out = {}
        for k in DELTA_KINDS:
            v = delta.get(k, 0.0)
            if not (_number(v) and math.isfinite(v) and 0 <= v < 1):
                raise ConfigError(f"delta['{k}'] must be a number in [0, 1), got {v!r}")
            out[k] = float(v)
        if not any(out.values()):
            raise ConfigError(f"delta must have at least one positive entry, got {dict(delta)!r}")
        return out
    raise ConfigError(f"delta must be a number in (0, 1) or a mapping over {', '.join(DELTA_KINDS)}, got {delta!r}")


def _plant_rows(A) -> list[list]:
    if isinstance(A, Decoupler):
        raise ConfigError("A: a Decoupler cannot be given a parameter box; pass the FOPDT model or the plant")
    if isinstance(A, TITOPlant):
        return [[A.g11, A.g12], [A.g21, A.g22]]
    if isinstance(A, np.ndarray):
        A = A.tolist()
    if not (isinstance(A, (list, tuple)) and len(A) == 2
            and all(isinstance(r, (list, tuple)) and len(r) == 2 for r in A)):
        raise ConfigError("A must be a TITOPlant or a 2x2 nested sequence of elements")
    _matrix(A)  # validates every element
    return [list(r) for r in A]


def _params(e) -> list[tuple[str, str, float]]:
    """(suffix, kind, value) of the varied parameters of one element."""
    if isinstance(e, TFElement):
        out = [("K", "K", e.K)] if e.K != 0 else []
        out += [(f"lag{k}", "T", t) for k, t in enumerate(e.lags)]
        out += [(f"lead{k}", "T", t) for k, t in enumerate(e.leads) if t != 0]
        return out + ([("L", "L", e.L)] if e.L > 0 else [])
    if isinstance(e, FOPDT):
        out = [("K", "K", e.K)]
        out += [("T", "T", e.T)] if e.T > 0 else []
        return out + ([("L", "L", e.L)] if e.L > 0 else [])
    return []


def parameter_box(A, delta) -> dict[str, tuple[float, float]]:
    """The box of plant parameters: every parameter ``p`` of a parametric element in ``[p(1 - d), p(1 + d)]``.

    Parametric elements are :class:`TFElement` (``K``, each lag and non-zero lead, ``L`` if ``> 0``)
    and :class:`FOPDT` (``K``, ``T``, ``L``); numbers, :class:`DelayTerm` and lists stay fixed.

    Parameters
    ----------
    A : TITOPlant or 2x2 nested sequence
        See :func:`characteristic_polynomial` (a Decoupler is refused: vary its plant instead).
    delta : float or mapping
        One relative half-width in ``(0, 1)`` for all parameters, or ``{"K": .., "T": .., "L": ..}``
        (values in ``[0, 1)``, missing kinds fixed, at least one positive).

    Returns
    -------
    dict
        ``"a11.K" -> (lo, hi)``, ``"a12.lag0"``, ``"a21.lead0"``, ``"a22.L"``, ... with ``lo <= hi``;
        kinds with a zero delta are left out.
    """
    rows = _plant_rows(A)
    d = _deltas(delta)
    box = {}
    for i in range(2):
        for j in range(2):
            for suffix, kind, v in _params(rows[i][j]):
                if d[kind] > 0:
                    lo, hi = v * (1 - d[kind]), v * (1 + d[kind])
                    box[f"a{i + 1}{j + 1}.{suffix}"] = (min(lo, hi), max(lo, hi))
    return box


def perturbed_plant(A, params: Mapping[str, float]) -> list[list]:
    """``A`` with the named parameters replaced (names as in :func:`parameter_box`).

    Parameters
    ----------
    A : TITOPlant or 2x2 nested sequence
    params : mapping
        ``name -> value``; names not given keep their nominal value.

    Returns
    -------
    list of list
        A 2x2 nested list of elements.
    """
    rows = _plant_rows(A)
    known = {f"a{i + 1}{j + 1}.{s}" for i in range(2) for j in range(2) for s, _, _ in _params(rows[i][j])}
    unknown = sorted(set(params) - known)
    if unknown:
        raise ConfigError(f"params: unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    out = [[None, None], [None, None]]
    for i in range(2):
        for j in range(2):
            e, pre = rows[i][j], f"a{i + 1}{j + 1}."

            def get(s, v, pre=pre):
                return float(params.get(pre + s, v))

            if isinstance(e, TFElement):
                out[i][j] = TFElement(
                    K=get("K", e.K),
                    leads=tuple(get(f"lead{k}", t) if t != 0 else 0.0 for k, t in enumerate(e.leads)),
                    lags=tuple(get(f"lag{k}", t) for k, t in enumerate(e.lags)),
                    L=get("L", e.L))
            elif isinstance(e, FOPDT):
                out[i][j] = FOPDT(K=get("K", e.K), T=get("T", e.T), L=get("L", e.L))
            else:
                out[i][j] = e
    return out


def _param_poly(e, params, pre: str, delay: str, pade_order: int) -> tuple[np.ndarray, np.ndarray]:
    """``(n, d)`` of a TFElement / FOPDT with the parameters in ``params`` (fast path of :func:`perturbed_plant`)."""
    K = params.get(pre + "K", e.K)
    L = params.get(pre + "L", e.L)
    pn, pd = _delay_cached(float(L), delay, pade_order)
    if isinstance(e, FOPDT):
        return _mul([K], pn), _mul([params.get(pre + "T", e.T), 1.0], pd)
    leads = [[params.get(f"{pre}lead{k}", t), 1.0] for k, t in enumerate(e.leads) if t != 0]
    lags = [[params.get(f"{pre}lag{k}", t), 1.0] for k, t in enumerate(e.lags)]
    return _mul([K], *leads, pn), _mul(*lags, pd)


def _exact(delay: str, pade_order: int) -> bool:
    return delay == "taylor" or pade_order == 1


def interval_characteristic_bounds(A, controllers, delta, *, delay: str = "taylor", pade_order: int = 2,
                                   samples: int = 0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bound of every coefficient of :func:`characteristic_polynomial` over :func:`parameter_box`.

    The polynomial is evaluated at the ``2^k`` vertices of the box
    (:func:`~heurtune.objectives.robustness.interval_characteristic_polynomial`, at most 16
    parameters) and, if ``samples > 0``, at that many uniformly drawn interior points, and the
    element-wise minimum and maximum are taken.

    **When the bounds are exact.** With ``delay="taylor"`` (``1 - L s``) or ``delay="pade"`` of order 1
    every coefficient is multilinear in the parameters: each parameter sits in one first-degree factor
    (``K`` and ``1 - L s`` or ``1 - L s/2`` in ``n_ij``, ``1 + T s`` and ``1 + L s/2`` in ``d_ij``) and
    every product of ``N`` contains ``n_ij`` or ``d_ij`` at most once. A multilinear function takes its
    extremes at vertices, so the vertex bounds are the exact per-coefficient hull. With a Pade
    approximant of order ``>= 2`` the coefficients contain ``L^2 ... L^{2n}`` and the vertex bounds are
    only an inner estimate (interior points may fall outside them); ``samples`` widens them, but no
    finite sample makes them rigorous. In every case Kharitonov then treats the coefficients as
    independent, so a pass is sufficient (conservative) and a fail is inconclusive for the parametric
    family.

    Parameters
    ----------
    A, controllers, delay, pade_order
        See :func:`characteristic_polynomial` (A without a Decoupler).
    delta : float or mapping
        See :func:`parameter_box`.
    samples : int
        Extra random interior points (``>= 0``).
    seed : int
        Seed of those points.

    Returns
    -------
    lower, upper : numpy.ndarray
        Highest power first, left-padded with zeros to a common length.
    """
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 0:
        raise ConfigError(f"samples must be an integer >= 0, got {samples!r}")
    box = parameter_box(A, delta)
    if not box:
        raise ConfigError("delta: A has no parameter to vary (no TFElement / FOPDT entries with that kind)")
    delay_approximation(1.0, delay, pade_order)  # validates delay and pade_order once
    rows = _plant_rows(A)
    ctrl = _controllers(controllers)
    fixed = [[None if _params(rows[i][j]) else _element_poly(_element_terms(rows[i][j], "A"), delay, pade_order)
              for j in range(2)] for i in range(2)]

    def poly(params):
        nds = [[fixed[i][j] if fixed[i][j] is not None
                else _param_poly(rows[i][j], params, f"a{i + 1}{j + 1}.", delay, pade_order)
                for j in range(2)] for i in range(2)]
        return _assemble(nds, ctrl)

    lo, hi = interval_characteristic_polynomial(poly, box)
    if samples:
        rng = np.random.default_rng(seed)
        names = list(box)
        bl = np.array([box[n][0] for n in names])
        bh = np.array([box[n][1] for n in names])
        for x in rng.uniform(bl, bh, size=(int(samples), len(names))):
            c = poly(dict(zip(names, x)))
            size = max(c.size, lo.size)
            c = np.concatenate([np.zeros(size - c.size), c])
            lo = np.concatenate([np.zeros(size - lo.size), lo])
            hi = np.concatenate([np.zeros(size - hi.size), hi])
            lo, hi = np.minimum(lo, c), np.maximum(hi, c)
    return lo, hi


# ----------------------------------------------------------------------------------------------
# Hurwitz / Kharitonov report
# ----------------------------------------------------------------------------------------------


def row_reduced_hurwitz(coeffs) -> np.ndarray:
    """The paper's "row-reduced Hurwitz matrix": :func:`hurwitz_matrix` made upper triangular by Gaussian elimination.

    Elimination without pivoting (row ``i`` minus ``H[i,k]/H[k,k]`` times row ``k``). The pivots are
    the ratios of successive Hurwitz determinants, ``U[k, k] = Delta_{k+1} / Delta_k``
    (``Delta_0 = 1``), so "no sign change on the diagonal" (paper 000 after eq. 37) is the Hurwitz
    criterion. Paper 000's Table 4 prints the transpose of this Hurwitz matrix (its eq. 36, the
    transpose for the reversed polynomial, whose roots are the reciprocals); a transpose has the
    same leading minors, hence the same pivots. If a pivot is exactly 0 (a vanishing
    determinant: not Hurwitz) the elimination stops there and the rows below it are ``nan``.

    Parameters
    ----------
    coeffs : array_like
        Highest power first (a negative leading coefficient is normalised as in :func:`hurwitz_matrix`).

    Returns
    -------
    numpy.ndarray
        Shape ``(n, n)``.
    """
    return row_reduce(hurwitz_matrix(coeffs))


def row_reduce(M) -> np.ndarray:
    """``M`` made upper triangular by Gaussian elimination without pivoting (the elimination of
    :func:`row_reduced_hurwitz`, for a matrix laid out as a source prints it).

    Parameters
    ----------
    M : array_like
        Square.

    Returns
    -------
    numpy.ndarray
        A float copy; below a zero pivot the rows are ``nan``.
    """
    U = np.array(M, dtype=float)
    n = U.shape[0]
    for k in range(n):
        piv = U[k, k]
        if piv == 0.0:
            U[k + 1:, :] = np.nan
            break
        for i in range(k + 1, n):
            if U[i, k] != 0.0:
                U[i, :] -= (U[i, k] / piv) * U[k, :]
                U[i, k] = 0.0
    return U


@dataclasses.dataclass(frozen=True)
class MimoKharitonovResult:
    """Outcome of :func:`kharitonov_hurwitz` / :func:`mimo_kharitonov_test`.

    Attributes
    ----------
    lower, upper : numpy.ndarray
        Coefficient bounds, highest power first (negated if the whole leading interval was negative).
    nominal : numpy.ndarray or None
        The nominal characteristic polynomial, when known.
    nominal_hurwitz : bool or None
        Whether it is Hurwitz.
    polynomials : tuple of 4 numpy.ndarray
        K1..K4 (order of :func:`~heurtune.objectives.robustness.kharitonov_polynomials`); empty if
        the leading interval contains 0.
    hurwitz_matrices, reduced_matrices : tuple of 4 numpy.ndarray
        :func:`hurwitz_matrix` and :func:`row_reduced_hurwitz` of each.
    determinants : tuple of 4 numpy.ndarray
        Hurwitz determinants ``Delta_1 .. Delta_n`` of each.
    hurwitz : tuple of 4 bool
        All determinants ``> tol``.
    robustly_stable : bool
        All four Hurwitz (then every polynomial of the coefficient box is).
    failing : tuple of str
        One line per failure, e.g. ``"K2: Delta_2 = -4"`` (first non-positive determinant), or the
        leading interval containing 0.
    exact_bounds : bool or None
        Whether ``lower, upper`` are the exact coefficient hull of the parameter box (None: a
        coefficient box given directly).
    """

    lower: np.ndarray
    upper: np.ndarray
    nominal: np.ndarray | None
    nominal_hurwitz: bool | None
    polynomials: tuple
    hurwitz_matrices: tuple
    reduced_matrices: tuple
    determinants: tuple
    hurwitz: tuple
    robustly_stable: bool
    failing: tuple
    exact_bounds: bool | None = None

    def summary(self) -> str:
        """One line: degree, verdict, the failures and the nominal verdict."""
        deg = self.lower.size - 1
        verdict = "robustly stable" if self.robustly_stable else "NOT robustly stable"
        out = f"Kharitonov, degree {deg}: {verdict}"
        if self.failing:
            out += " (" + "; ".join(self.failing) + ")"
        if self.nominal_hurwitz is not None:
            out += f"; nominal {'Hurwitz' if self.nominal_hurwitz else 'not Hurwitz'}"
        if self.exact_bounds is not None:
            out += "; bounds exact" if self.exact_bounds else "; bounds estimated (Pade order >= 2)"
        return out


def kharitonov_hurwitz(lower, upper, *, tol: float = 0.0, nominal=None,
                       exact_bounds: bool | None = None) -> MimoKharitonovResult:
    """Kharitonov test of a coefficient box with each polynomial's Hurwitz and row-reduced Hurwitz matrices.

    Parameters
    ----------
    lower, upper : array_like
        Coefficient bounds, highest power first, equal lengths, ``lower <= upper``.
    tol : float
        A determinant must exceed ``tol`` (``>= 0``).
    nominal : array_like, optional
        A nominal polynomial to report on (``nominal_hurwitz``).
    exact_bounds : bool, optional
        Recorded in the result.

    Returns
    -------
    MimoKharitonovResult
        If the leading interval contains 0 the degree can drop and the family is reported as not
        robustly stable with no Kharitonov polynomials.
    """
    if not (_number(tol) and math.isfinite(tol) and tol >= 0):
        raise ConfigError(f"tol must be a finite number >= 0, got {tol!r}")
    try:
        lo = np.asarray(lower, dtype=float).reshape(-1)
        hi = np.asarray(upper, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ConfigError("lower and upper must be arrays of real numbers") from None
    if lo.size < 2 or lo.shape != hi.shape:
        raise ConfigError(f"lower and upper must have equal lengths >= 2, got {lo.size} and {hi.size}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(lo > hi):
        raise ConfigError("lower and upper must be finite with lower <= upper")
    nom, nom_ok = None, None
    if nominal is not None:
        nom = _real_poly(nominal, "nominal")
        nom_ok = bool(nom.size == 1 or np.all(hurwitz_determinants(nom) > tol))
    if hi[0] < 0:
        lo, hi = -hi, -lo
    if lo[0] <= 0.0:
        msg = f"leading coefficient interval [{lo[0]:.6g}, {hi[0]:.6g}] contains 0 (degree can drop)"
        return MimoKharitonovResult(lower=lo, upper=hi, nominal=nom, nominal_hurwitz=nom_ok, polynomials=(),
                                    hurwitz_matrices=(), reduced_matrices=(), determinants=(), hurwitz=(),
                                    robustly_stable=False, failing=(msg,), exact_bounds=exact_bounds)
    polys = kharitonov_polynomials(lo, hi)
    dets = tuple(hurwitz_determinants(p) for p in polys)
    ok = tuple(bool(np.all(d > tol)) for d in dets)
    failing = []
    for k, (d, good) in enumerate(zip(dets, ok)):
        if not good:
            j = int(np.argmax(~(d > tol)))
            failing.append(f"K{k + 1}: Delta_{j + 1} = {d[j]:.6g}")
    return MimoKharitonovResult(
        lower=lo, upper=hi, nominal=nom, nominal_hurwitz=nom_ok, polynomials=polys,
        hurwitz_matrices=tuple(hurwitz_matrix(p) for p in polys),
        reduced_matrices=tuple(row_reduced_hurwitz(p) for p in polys),
        determinants=dets, hurwitz=ok, robustly_stable=all(ok), failing=tuple(failing), exact_bounds=exact_bounds)


def mimo_kharitonov_test(A, controllers, delta, *, delay: str = "taylor", pade_order: int = 2, samples: int = 0,
                         seed: int = 0, tol: float = 0.0) -> MimoKharitonovResult:
    """Robust stability of the 2x2 loop over a plant-parameter box by Kharitonov's theorem (paper 000 sec. IV-A).

    Nominal :func:`characteristic_polynomial`, coefficient bounds from
    :func:`interval_characteristic_bounds`, then :func:`kharitonov_hurwitz`.

    Parameters
    ----------
    A, controllers, delay, pade_order
        See :func:`characteristic_polynomial` (A without a Decoupler).
    delta : float or mapping
        See :func:`parameter_box`.
    samples, seed
        See :func:`interval_characteristic_bounds`.
    tol : float
        See :func:`kharitonov_hurwitz`.

    Returns
    -------
    MimoKharitonovResult
    """
    nominal = characteristic_polynomial(A, controllers, delay=delay, pade_order=pade_order)
    lo, hi = interval_characteristic_bounds(A, controllers, delta, delay=delay, pade_order=pade_order,
                                            samples=samples, seed=seed)
    return kharitonov_hurwitz(lo, hi, tol=tol, nominal=nominal, exact_bounds=_exact(delay, pade_order))


# ----------------------------------------------------------------------------------------------
# Checks of printed Kharitonov polynomials and of paper 000's chain
# ----------------------------------------------------------------------------------------------

# Lower-bound sets per power k mod 4 in the order K1..K4 of robustness.kharitonov_polynomials.
_LOWER_AT = ({0, 2}, {0, 3}, {1, 3}, {1, 2})


def kharitonov_pattern_mismatches(polys) -> tuple[tuple[int, ...], list[str]]:
    """Whether four polynomials can be the Kharitonov polynomials of one coefficient box.

    Kharitonov polynomials share their end points: at every power two of them take the lower and
    two the upper bound, in the period-4 pattern of
    :func:`~heurtune.objectives.robustness.kharitonov_polynomials` (in increasing powers K1 ``l l u u``,
    K2 ``u u l l``, K3 ``l u u l``, K4 ``u l l u``). All 24 assignments of the given polynomials to
    K1..K4 are tried (papers number them differently).

    Parameters
    ----------
    polys : sequence of 4 array_like
        Highest power first, equal lengths.

    Returns
    -------
    perm, mismatches : tuple of int, list of str
        The best assignment (``perm[k]`` is the index of the given polynomial used as K(k+1)) and, for
        it, one line per power whose values do not fit (empty when they are Kharitonov polynomials).
    """
    try:
        P = np.array([np.asarray(p, dtype=float).reshape(-1) for p in polys])
    except (TypeError, ValueError):
        raise ConfigError("polys must be four coefficient arrays of equal length") from None
    if P.ndim != 2 or P.shape[0] != 4 or not np.all(np.isfinite(P)):
        raise ConfigError(f"polys must be four finite coefficient arrays of equal length, got shape {P.shape}")
    inc = P[:, ::-1]
    best = None
    for perm in itertools.permutations(range(4)):
        bad = []
        for k in range(inc.shape[1]):
            low = [inc[perm[m], k] for m in _LOWER_AT[k % 4]]
            up = [inc[perm[m], k] for m in range(4) if m not in _LOWER_AT[k % 4]]
            if low[0] != low[1] or up[0] != up[1] or low[0] > up[0]:
                bad.append(f"s^{k}: lower pair {low[0]:g}, {low[1]:g}; upper pair {up[0]:g}, {up[1]:g}")
        if best is None or len(bad) < len(best[1]):
            best = (perm, bad)
    return best


def paper000_qts_chain(source: str = "eq62", *, off_diagonal: float = 1.0) -> np.ndarray:
    """Recompute paper 000's QTS characteristic polynomial (appendix eq. 59-66) from its printed numbers.

    ``det[I + C(s) A(s)]`` with ``A`` the FOPDT model of eq. 59 / 62 (``1`` off the diagonal as printed,
    change with ``off_diagonal``; the decoupled loop would have 0) and ``C`` the PID of eq. 60 / 63, by
    :func:`characteristic_polynomial` with Taylor delays.

    Parameters
    ----------
    source : {"eq62", "eq59", "eq64"}
        ``"eq62"``: eq. 62 as printed, ``a11 = (2.332 - 0.16 s)/(86.35 s + 1)``,
        ``a22 = (2.119 - 0.3 s)/(110.65 s + 1)``, with eq. 63's ``C`` (``Ki1 = 0.285``).
        ``"eq59"``: eq. 59 with ``e^{-Ls} = 1 - Ls`` (``0.069``, ``0.061``, ``110.659``) and eq. 60's
        ``C`` (``Ki1 = 0.2985``). ``"eq64"``: the diagonal entries ``c_i a_ii`` as printed in eq. 64
        (numerators ``-1.25 s^3 + 13.73 s^2 - 65.25 s + 0.66`` and ``-1.5 s^3 + 19.57 s^2 - 79.4 s + 0.65``
        over ``s (86.35 s + 1)`` and ``s (110.65 s + 1)``), the off-diagonal product from eq. 63.
    off_diagonal : float
        The value of ``a12 = a21``.

    Returns
    -------
    numpy.ndarray
        Degree 6, highest power first.

    Notes
    -----
    Findings (off-diagonal 1 as printed):

    - ``"eq62"`` gives ``-859243 s^6 - 5896701 s^5 - 10195696 s^4 - 376050 s^3 - 202.45 s^2
      + 59.88 s + 0.34262``: with the signs and powers of ten dropped only the leading two
      coefficients read as eq. 66 (859.2, 589.7; then 102.0, 376.1, 202.4, 59.9, 0.3426 against
      101.9, 408.5, 485.8, 129.9, 0.3421). Eq. 66 does not follow from eqs. 62-63.
    - ``"eq64"`` gives ``-859245.8 s^6 - 5896514 s^5 - 10194530 s^4 - 408507.1 s^3 - 485.82 s^2
      - 129.86 s + 0.342075``, whose magnitudes with the powers of ten dropped are eq. 66 to every
      printed digit (859.2, 589.7, 101.9, 408.5, 485.8, 129.9, 0.3421). Eq. 66 is this polynomial
      with its signs and exponents lost; eq. 64's ``s`` terms carry a sign error
      (``(7.82 s^2 + 28 s + 0.285)(2.332 - 0.16 s)`` has ``+65.25 s``) and its loop-2 entry uses
      ``0.129 = 2.119 * 0.061`` where eq. 62 prints 0.3.
    - Every variant has a sign change (negative leading, positive constant coefficient), so none
      is Hurwitz; eq. 66 as printed (all positive) is not Hurwitz either (complex pair at
      ``0.492 +- 0.718j``).
    """
    P = _mul
    if not (_number(off_diagonal) and math.isfinite(off_diagonal)):
        raise ConfigError(f"off_diagonal must be a finite number, got {off_diagonal!r}")
    nc2 = np.array([11.5, 37.5, 0.305])
    if source == "eq62":
        A = [[DelayTerm([-0.16, 2.332], [86.35, 1.0]), off_diagonal],
             [off_diagonal, DelayTerm([-0.3, 2.119], [110.65, 1.0])]]
        return characteristic_polynomial(A, [(28.0, 0.285, 7.82), (37.5, 0.305, 11.5)], delay="taylor")
    if source == "eq59":
        A = [[TFElement(K=2.332, lags=(86.35,), L=0.069), off_diagonal],
             [off_diagonal, TFElement(K=2.119, lags=(110.659,), L=0.061)]]
        return characteristic_polynomial(A, [(28.0, 0.2985, 7.82), (37.5, 0.305, 11.5)], delay="taylor")
    if source == "eq64":
        nc1 = np.array([7.82, 28.0, 0.285])
        d11, d22 = np.array([86.35, 1.0]), np.array([110.65, 1.0])
        b1 = _add(P([1.0, 0.0], d11), [-1.25, 13.73, -65.25, 0.66])
        b2 = _add(P([1.0, 0.0], d22), [-1.5, 19.57, -79.4, 0.65])
        return _add(P(b1, b2), -P([off_diagonal ** 2], nc1, nc2, d11, d22))
    raise ConfigError(f"source must be 'eq62', 'eq59' or 'eq64', got {source!r}")
