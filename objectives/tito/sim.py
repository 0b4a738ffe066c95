"""Fixed-step simulation of a TITO plant with decoupler and decentralised PI/PID controllers.

Loop (all signals are deviations from the operating point; the loop starts at rest)::

    r_i --(+)--> e_i --> c_i --> v_i --> D(s) --> u --(+ d_in + n_in)--> G(s) --(+ d_out)--> y --(+ noise)--> y_m
          (-) y_m                                                                                   |
           ^----------------------------------------------------------------------------------------+

Discretisation (step ``dt``, default 0.1 s, small against the lags of every preset):

- every rational part (each plant element ``K prod(1 + s Tz) / prod(1 + s Tp)``, each decoupler
  ratio, each controller) is realised as a SISO state space and discretised **exactly** with a
  zero-order hold on its (sampled) input, via ``scipy.linalg.expm`` of the augmented matrix;
- every dead time is an integer-sample delay line of ``round(L / dt)`` samples. A delay that is
  not a multiple of ``dt`` (within 1e-9 s) is rounded to the nearest sample; the rounding error is
  at most ``dt / 2`` per delay and the largest one is reported in ``df.attrs["delay_rounding"]``;
- with a step (or any held) input the plant part is exact at the samples. The controllers act on
  the sampled measurement held over each step (a sampled-data controller), which differs from a
  continuous controller by terms of order ``dt``.

Parameter variation (``TITOScenario.variation = delta``, e.g. +-0.1, 0.2, 0.3) multiplies the
plant parameters named in ``TITOScenario.vary`` (default: every element's gain ``K``, lag time
constants ``lags`` and dead time ``L``; ``leads`` may be added) by ``1 + delta``. The decoupler
and the controllers keep their nominal design (the decoupler is realised from
``decoupler.plant``), which is what a robustness test needs.

Noise follows the Simulink band-limited white noise convention: with ``noise_power = P`` the
measurement noise of each loop is a zero-mean Gaussian sequence of variance ``P / dt`` held over
each step (so its spectral density is ``P`` for ``dt`` small), drawn with
``numpy.random.default_rng(noise_seed)``.

Input noise ``n_in`` (``input_noise_power``, off by default) follows the same convention and is
added to the plant inputs where the input disturbance enters (after the decoupler; the recorded
``u`` is the decoupler output, before both). It has a generator of its own (:func:`input_noise`):
``numpy.random.default_rng(input_noise_seed)``, or, without ``input_noise_seed``, one derived
from ``noise_seed`` as ``numpy.random.SeedSequence(noise_seed, spawn_key=(1,))``, a stream
independent of the measurement noise's. Either way the measurement-noise draws do not change
when input noise is added, and with ``input_noise_power = 0`` the simulation is bit for bit the
one without the key.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pandas as pd
import scipy.linalg
import scipy.signal

from heurtune.core.errors import ConfigError

from . import kernels as _k
from .model import Decoupler, ParallelPID, PIController, PIDController, TFElement, TITOPlant

__all__ = ["LOOPS", "TITOScenario", "TITOSimulator", "check_sampling", "controller_tf", "discretise_rational",
           "input_noise", "loop_metrics", "measurement_noise", "simulate_tito", "vary_plant"]

DELAY_TOL = 1e-9
_VARY_KEYS = ("K", "lags", "leads", "L")
# Fields of TITOScenario that enter its identity only when input noise is on (so that the
# problem_id of every scenario without input noise stays what it was before they existed).
_INPUT_NOISE_FIELDS = ("input_noise_power", "input_noise_seed")
LOOPS = ("sampled", "continuous")


def _check_steps(name: str, steps) -> tuple:
    """``[(time, value), ...]`` -> sorted tuple of float pairs."""
    try:
        out = tuple((float(t), float(v)) for t, v in steps)
    except (TypeError, ValueError):
        raise ConfigError(f"scenario: {name} must be a list of (time, value) pairs, got {steps!r}") from None
    for t, v in out:
        if not (math.isfinite(t) and t >= 0 and math.isfinite(v)):
            raise ConfigError(f"scenario: {name} needs finite times >= 0 and finite values, got {steps!r}")
    return tuple(sorted(out))


def _check_pair(name: str, val) -> tuple:
    try:
        if np.ndim(val) == 0:
            out = (float(val), float(val))
        else:
            a, b = val
            out = (float(a), float(b))
    except (TypeError, ValueError):
        raise ConfigError(f"scenario: {name} must be a number or a pair of numbers, got {val!r}") from None
    if not all(math.isfinite(v) for v in out):
        raise ConfigError(f"scenario: {name} must be finite, got {val!r}")
    return out


def _check_seed(name: str, val, optional: bool = False):
    if optional and val is None:
        return None
    if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < 0:
        allowed = "an integer >= 0" + (" or None" if optional else "")
        raise ConfigError(f"scenario: {name} must be {allowed}, got {val!r}")
    return int(val)


@dataclasses.dataclass(frozen=True)
class TITOScenario:
    """Test scenario of :func:`simulate_tito`.

    Parameters
    ----------
    horizon : float
        Final time (s); samples at ``0, dt, ..., n dt`` with ``n = round(horizon / dt)``.
    dt : float
        Fixed step (s), default 0.1.
    setpoints : pair of lists of ``(time, value)``
        Per loop, the set-point jumps to ``value`` at ``time`` (it is 0 before the first step).
        Default: both loops step to 1 at t = 0.
    input_disturbance : (time, (d1, d2))
        Step added to both plant inputs from ``time`` on (paper 000: 500 s). Default magnitude 0.
    output_disturbance : (time, (d1, d2))
        Step added to both outputs from ``time`` on (paper 000: 800 s). Default magnitude 0.
    noise_power : float or pair
        Band-limited white-noise power of the measurement, per loop (variance ``P / dt`` per
        sample); 0 for none.
    noise_seed : int
        Seed of the measurement noise (>= 0).
    variation : float
        Relative plant-parameter change ``delta`` in (-1, 1) (e.g. +-0.1, 0.2, 0.3).
    vary : tuple of str
        Which parameters ``variation`` scales: any of ``K``, ``lags``, ``leads``, ``L``.
    input_noise_power : float or pair
        Band-limited white-noise power added to each plant input (after the decoupler, where
        ``input_disturbance`` enters; variance ``P / dt`` per sample); 0 (default) for none.
    input_noise_seed : int or None
        Seed of the input noise; None (default) derives it from ``noise_seed`` (see the module
        docstring and :func:`input_noise`).
    loop : {"sampled", "continuous"}
        ``"sampled"`` (default): this module's loop, controllers and decoupler sampled at ``dt``.
        ``"continuous"``: :class:`~heurtune.objectives.tito.continuous.ContinuousTITOSimulator`,
        the continuous loop with exact dead times on the step ``dt`` (noise held over each step).
    allow_coarse_sampling : bool
        On the sampled loop, a derivative filter ``Tf`` shorter than ``10 dt`` is an error
        (:func:`check_sampling`) unless this is True (default False). Not part of the identity:
        it changes no number.
    tolerance : float or None
        The continuous loop only: each run chooses its step to this tolerance on the outputs
        (:class:`~heurtune.objectives.tito.continuous.ContinuousTITOSimulator`); ``dt`` is then
        the noise's sample time alone. None (default): the step is ``dt``.

    A step time ``t`` acts from the first sample ``k`` with ``k dt >= t - 1e-9``.
    """

    horizon: float = 1000.0
    dt: float = 0.1
    setpoints: tuple = (((0.0, 1.0),), ((0.0, 1.0),))
    input_disturbance: tuple = (500.0, (0.0, 0.0))
    output_disturbance: tuple = (800.0, (0.0, 0.0))
    noise_power: object = 0.0
    noise_seed: int = 0
    variation: float = 0.0
    vary: tuple = ("K", "lags", "L")
    input_noise_power: object = 0.0
    input_noise_seed: int | None = None
    loop: str = "sampled"
    allow_coarse_sampling: bool = False
    tolerance: float | None = None

    def __post_init__(self):
        try:
            horizon, dt, variation = float(self.horizon), float(self.dt), float(self.variation)
        except (TypeError, ValueError):
            raise ConfigError("scenario: horizon, dt and variation must be numbers") from None
        if not (math.isfinite(dt) and dt > 0):
            raise ConfigError(f"scenario: dt must be finite and > 0, got {self.dt!r}")
        if not (math.isfinite(horizon) and horizon >= dt):
            raise ConfigError(f"scenario: horizon must be finite and >= dt, got {self.horizon!r}")
        if not (math.isfinite(variation) and -1 < variation < 1):
            raise ConfigError(f"scenario: variation must lie in (-1, 1), got {self.variation!r}")
        sp = self.setpoints
        if isinstance(sp, (str, bytes)) or not hasattr(sp, "__len__") or len(sp) != 2:
            raise ConfigError(f"scenario: setpoints must be two lists of (time, value), got {sp!r}")
        setpoints = (_check_steps("setpoints[0]", sp[0]), _check_steps("setpoints[1]", sp[1]))
        dists = []
        for name in ("input_disturbance", "output_disturbance"):
            val = getattr(self, name)
            try:
                t, mag = val
                t = float(t)
            except (TypeError, ValueError):
                raise ConfigError(f"scenario: {name} must be (time, (d1, d2)), got {val!r}") from None
            if not (math.isfinite(t) and t >= 0):
                raise ConfigError(f"scenario: {name} time must be finite and >= 0, got {t!r}")
            dists.append((t, _check_pair(name, mag)))
        power = _check_pair("noise_power", self.noise_power)
        if min(power) < 0:
            raise ConfigError(f"scenario: noise_power must be >= 0, got {self.noise_power!r}")
        if isinstance(self.noise_seed, bool) or not isinstance(self.noise_seed, (int, np.integer)):
            raise ConfigError(f"scenario: noise_seed must be an integer, got {self.noise_seed!r}")
        try:
            in_power = _check_pair("input_noise_power", self.input_noise_power)
        except ConfigError:
            in_power = (-1.0, -1.0)
        if min(in_power) < 0:
            raise ConfigError(f"scenario: input_noise_power must be a number >= 0 or a pair [P1, P2] of numbers "
                              f">= 0, got {self.input_noise_power!r}")
        in_seed = _check_seed("input_noise_seed", self.input_noise_seed, optional=True)
        vary = (self.vary,) if isinstance(self.vary, str) else tuple(self.vary)
        bad = [v for v in vary if v not in _VARY_KEYS]
        if bad:
            raise ConfigError(
                f"scenario: unknown vary key(s) {', '.join(map(str, bad))}; allowed: {', '.join(_VARY_KEYS)}"
            )
        if self.loop not in LOOPS:
            raise ConfigError(f"scenario: loop must be one of {', '.join(LOOPS)}, got {self.loop!r}")
        if not isinstance(self.allow_coarse_sampling, (bool, np.bool_)):
            raise ConfigError("scenario: allow_coarse_sampling must be true or false, "
                              f"got {self.allow_coarse_sampling!r}")
        if self.tolerance is not None:
            tol = self.tolerance
            if isinstance(tol, bool) or not isinstance(tol, (int, float, np.integer, np.floating)) \
                    or not (math.isfinite(tol) and tol > 0):
                raise ConfigError(f"scenario: tolerance must be a finite number > 0, got {tol!r}")
            if self.loop != "continuous":
                raise ConfigError(f"scenario: tolerance sets the continuous loop's step; loop is {self.loop!r} "
                                  "(use loop = 'continuous', or the sampled loop's step alone)")
            object.__setattr__(self, "tolerance", float(tol))
        for key, val in (("horizon", horizon), ("dt", dt), ("variation", variation), ("setpoints", setpoints),
                         ("input_disturbance", dists[0]), ("output_disturbance", dists[1]),
                         ("noise_power", power), ("noise_seed", int(self.noise_seed)), ("vary", vary),
                         ("input_noise_power", in_power), ("input_noise_seed", in_seed)):
            object.__setattr__(self, key, val)

    @property
    def has_input_noise(self) -> bool:
        """Whether any plant input gets noise (``input_noise_power`` above 0 on a loop)."""
        return max(self.input_noise_power) > 0.0

    def identity(self) -> dict:
        """The fields that define the scenario, as a plain dict (hashed into a problem_id).

        ``input_noise_power`` and ``input_noise_seed`` are included only when input noise is on,
        so that every scenario without it keeps the identity (and problem_id) it had before
        those fields existed.

        Returns
        -------
        dict
            ``dataclasses.asdict`` of the scenario, less the input-noise fields when they are off.
        """
        out = dataclasses.asdict(self)
        out.pop("allow_coarse_sampling")  # permits a loop, changes no number
        if not self.has_input_noise:
            for key in _INPUT_NOISE_FIELDS:
                out.pop(key)
        if self.loop == "sampled":  # the identity every sampled scenario had before the key existed
            out.pop("loop")
        if self.tolerance is None:  # a fixed step: the identity it had before the key existed
            out.pop("tolerance")
        return out

    @property
    def n_steps(self) -> int:
        return round(self.horizon / self.dt)

    def time(self) -> np.ndarray:
        return np.arange(self.n_steps + 1) * self.dt


# --------------------------------------------------------------------------------------------
# Realisation
# --------------------------------------------------------------------------------------------


COARSE_FACTOR = 10.0


def check_sampling(scenario: TITOScenario, controllers=None, N=None) -> None:
    """Refuse a sampled loop too coarse for its derivative filters (one line).

    The sampled loop holds the controllers' outputs over ``dt``; a derivative filter ``Tf``
    shorter than ``10 dt`` is then not followed (paper 000's designs oscillate at dt = 0.1 s
    where the continuous loop settles). Nothing is checked on the continuous loop or with
    ``allow_coarse_sampling``.

    Parameters
    ----------
    scenario : TITOScenario
    controllers : pair, optional
        Explicit controllers: each filter ``Tf`` of a controller with a derivative is checked.
    N : float, optional
        For a PID tuning problem (no explicit controllers): its filter ratio. Its candidates'
        filters ``Tf = Td / N`` go below ``10 dt`` for every ``Td < 10 N dt``, so such a
        problem is refused on the sampled loop.

    Raises
    ------
    ConfigError
        Naming ``dt`` and the filter, and the two ways out.
    """
    if scenario.loop != "sampled" or scenario.allow_coarse_sampling:
        return
    dt = scenario.dt
    limit = COARSE_FACTOR * dt
    way_out = ("run the continuous loop ([scenario] tolerance = X, or neither sample_time nor dt), or "
               "allow_coarse_sampling = true to keep the sampled loop")
    if controllers is None:
        if N is not None:
            raise ConfigError(f"scenario: the sampled loop at dt = {dt:g} s cannot follow a PID tuning problem's "
                              f"derivative filters (Tf = Td / N, N = {N:g}: below 10 dt = {limit:g} s for every "
                              f"Td below {limit * N:g} s); {way_out}")
        return
    for i, c in enumerate(controllers, start=1):
        # a PIController has no filter; anything else is refused later, by controller_tf
        kd = c.parallel()[2] if hasattr(c, "parallel") else 0.0
        tf = float(getattr(c, "Tf", 0.0))
        if kd != 0.0 and 0.0 < tf < limit:
            raise ConfigError(f"scenario: dt = {dt:g} s exceeds a tenth of controller {i}'s derivative filter "
                              f"Tf = {tf:g} s; {way_out}")


def measurement_noise(scenario: TITOScenario) -> np.ndarray:
    """The measurement noise under ``scenario``, one column per loop.

    Zero-mean Gaussian, variance ``P_i / dt`` per sample (``P_i = noise_power[i]``), drawn as
    ``numpy.random.default_rng(noise_seed).standard_normal((n + 1, 2))`` scaled per column: the
    sampled loop adds sample ``k`` to the outputs at ``k dt``, the continuous loop holds it over
    ``[k dt, (k + 1) dt)``.

    Parameters
    ----------
    scenario : TITOScenario

    Returns
    -------
    numpy.ndarray, shape (n + 1, 2)
        Zeros when ``noise_power`` is 0 on both loops.
    """
    return _white_noise(scenario.noise_seed, scenario.noise_power, scenario)


def _white_noise(seed, power, scenario: TITOScenario) -> np.ndarray:
    """``n + 1`` samples per loop from ``default_rng(seed)``, variance ``power / dt``."""
    rng = np.random.default_rng(seed)
    return np.ascontiguousarray(rng.standard_normal((scenario.n_steps + 1, 2))
                                * np.sqrt(np.array(power) / scenario.dt))


def input_noise(scenario: TITOScenario) -> np.ndarray:
    """The noise added to the plant inputs under ``scenario``, one column per input.

    Zero-mean Gaussian, variance ``P_i / dt`` per sample (Simulink band-limited white noise of
    power ``P_i = input_noise_power[i]``), drawn as ``rng.standard_normal((n + 1, 2))`` scaled per
    column, with ``rng = numpy.random.default_rng(input_noise_seed)``, or, when
    ``input_noise_seed`` is None, ``default_rng(numpy.random.SeedSequence(noise_seed,
    spawn_key=(1,)))``: a stream of its own, so that the measurement noise (drawn from
    ``default_rng(noise_seed)``) is the same with or without input noise.

    Parameters
    ----------
    scenario : TITOScenario

    Returns
    -------
    numpy.ndarray, shape (n + 1, 2)
        Zeros when ``input_noise_power`` is 0 on both loops.
    """
    if not isinstance(scenario, TITOScenario):
        raise ConfigError(f"scenario: must be a TITOScenario, got {type(scenario).__name__}")
    if not scenario.has_input_noise:
        return np.zeros((scenario.n_steps + 1, 2))
    seed = scenario.input_noise_seed
    if seed is None:
        seed = np.random.SeedSequence(scenario.noise_seed, spawn_key=(1,))
    return _white_noise(seed, scenario.input_noise_power, scenario)


def _poly(K: float, tcs) -> np.ndarray:
    """``K prod(1 + s T)`` as coefficients, highest power first (``T = 0`` factors dropped)."""
    p = np.array([K], dtype=np.float64)
    for t in tcs:
        if t != 0.0:
            p = np.polymul(p, [t, 1.0])
    return p


def discretise_rational(num, den, dt: float):
    """Exact ZOH discretisation of the proper SISO ``num(s)/den(s)``.

    Returns ``(Ad, Bd, C, D)`` with ``x[k+1] = Ad x[k] + Bd w[k]``, ``y[k] = C x[k] + D w[k]``
    (``Ad`` of shape ``(m, m)``, ``Bd`` and ``C`` of shape ``(m,)``).

    Parameters
    ----------
    num, den : array_like
        Polynomial coefficients, highest power first.
    dt : float
        The sample period.
    """
    num = np.trim_zeros(np.atleast_1d(np.asarray(num, dtype=np.float64)), "f")
    den = np.trim_zeros(np.atleast_1d(np.asarray(den, dtype=np.float64)), "f")
    if den.size == 0:
        raise ConfigError("discretise: zero denominator")
    if num.size == 0:
        return np.zeros((0, 0)), np.zeros(0), np.zeros(0), 0.0
    if num.size > den.size:
        raise ConfigError(f"discretise: improper transfer function (numerator degree {num.size - 1} > "
                          f"denominator degree {den.size - 1})")
    if den.size == 1:
        return np.zeros((0, 0)), np.zeros(0), np.zeros(0), float(num[0] / den[0])
    A, B, C, D = scipy.signal.tf2ss(num, den)
    m = A.shape[0]
    M = np.zeros((m + 1, m + 1))
    M[:m, :m] = A
    M[:m, m] = B[:, 0]
    E = scipy.linalg.expm(M * dt)
    return E[:m, :m], E[:m, m].copy(), C[0].copy(), float(D[0, 0])


def vary_plant(plant: TITOPlant, variation: float, vary=("K", "lags", "L")) -> TITOPlant:
    """Plant with the parameters named in ``vary`` of every element multiplied by ``1 + variation``.

    Parameters
    ----------
    plant : TITOPlant
    variation : float
        Relative change (``0.1``: +10 %).
    vary : iterable of {"K", "lags", "L"}

    Returns
    -------
    TITOPlant
    """
    f = 1.0 + float(variation)

    def one(e: TFElement) -> TFElement:
        return TFElement(
            K=e.K * f if "K" in vary else e.K,
            leads=tuple(t * f for t in e.leads) if "leads" in vary else e.leads,
            lags=tuple(t * f for t in e.lags) if "lags" in vary else e.lags,
            L=e.L * f if "L" in vary else e.L,
        )

    return TITOPlant(g11=one(plant.g11), g12=one(plant.g12), g21=one(plant.g21), g22=one(plant.g22),
                     name=f"{plant.name}*{f:g}" if variation else plant.name)


def controller_tf(c, i: int):
    """Transfer function of one controller.

    Parameters
    ----------
    c : PIController, PIDController or ParallelPID
    i : int
        Its loop (1 or 2), named in errors.

    Returns
    -------
    num, den : array_like
        Polynomial coefficients, highest power first.

    Raises
    ------
    ConfigError
        One line, for a controller that cannot be realised (non-finite gains, a derivative
        without its filter).
    """
    if isinstance(c, PIController):
        Kc, Ti = float(c.Kc), float(c.Ti)
        if not (math.isfinite(Kc) and math.isfinite(Ti) and Ti > 0):
            raise ConfigError(f"controller {i}: PI needs finite Kc and Ti > 0, got Kc={c.Kc!r}, Ti={c.Ti!r}")
        return [Kc * Ti, Kc], [Ti, 0.0]
    if isinstance(c, PIDController):
        Kc, Ti, Td, Tf = (float(v) for v in (c.Kc, c.Ti, c.Td, c.Tf))
        if not all(math.isfinite(v) for v in (Kc, Ti, Td, Tf)) or Ti <= 0 or Td < 0 or Tf < 0:
            raise ConfigError(f"controller {i}: PID needs finite Kc, Ti > 0, Td >= 0, Tf >= 0")
        if Td > 0 and Tf == 0:
            raise ConfigError(f"controller {i}: PID with Td > 0 needs a derivative filter Tf > 0")
        num = Kc * np.polymul([Ti, 1.0], [Td, 1.0])
        den = np.polymul([Ti, 0.0], [Tf, 1.0])
        return num, den
    if isinstance(c, ParallelPID):
        vals = (float(c.Kp), float(c.Ki), float(c.Kd), float(c.Tf))
        if not all(math.isfinite(v) for v in vals) or vals[3] < 0:
            raise ConfigError(f"controller {i}: parallel PID needs finite gains and Tf >= 0, got {c!r}")
        if vals[2] != 0.0 and vals[3] == 0.0:
            raise ConfigError(f"controller {i}: parallel PID with Kd != 0 needs a filter Tf > 0")
        return c.rational()
    raise ConfigError(f"controller {i}: must be a PIController, PIDController or ParallelPID, got {type(c).__name__}")


def _decoupler_entries(dec: Decoupler | None):
    """``[(num, den, delay)]`` for D11, D12, D21, D22 (continuous, delay in s)."""
    if dec is None:
        return [([1.0], [1.0], 0.0), ([0.0], [1.0], 0.0), ([0.0], [1.0], 0.0), ([1.0], [1.0], 0.0)]
    if not isinstance(dec, Decoupler):
        raise ConfigError(f"decoupler: must be a Decoupler (see inverted_decoupler) or None, got {type(dec).__name__}")
    p = dec.plant
    c1, c2 = dec.column_delays

    def ratio(num: TFElement, den: TFElement, col_delay: float):
        n = np.polymul(_poly(-num.K, num.leads), _poly(1.0, den.lags))
        d = np.polymul(_poly(den.K, den.leads), _poly(1.0, num.lags))
        return n, d, num.L - den.L + col_delay

    unit1 = ([1.0], [1.0], c1)
    unit2 = ([1.0], [1.0], c2)
    if dec.case == 1:
        return [unit1, ratio(p.g12, p.g11, c2), ratio(p.g21, p.g22, c1), unit2]
    return [ratio(p.g22, p.g21, c1), unit2, unit1, ratio(p.g11, p.g12, c2)]


def _delay_samples(label: str, L: float, dt: float):
    if L < -DELAY_TOL:
        raise ConfigError(f"{label}: negative delay {L:g} s is not realisable")
    nd = round(max(L, 0.0) / dt)
    return nd, abs(nd * dt - L)


def _step_signal(t: np.ndarray, steps, initial: float = 0.0) -> np.ndarray:
    out = np.full(t.shape, initial)
    for ts, v in steps:
        out[t >= ts - 1e-9] = v
    return out


class TITOSimulator:
    """The closed loop of one plant, decoupler and scenario, run for many controller pairs.

    The plant and decoupler blocks and the scenario's signals are realised once; each
    :meth:`run` only discretises the two controllers. :func:`simulate_tito` is the one-off form.

    Parameters
    ----------
    plant : TITOPlant
        Nominal plant (``scenario.variation`` is applied to it).
    decoupler : Decoupler or None
        ``None`` means ``D = I`` (plain decentralised control).
    scenario : TITOScenario, default ``TITOScenario()``

    Attributes
    ----------
    t, r : numpy.ndarray
        Sample times and set-points.
    d_in : numpy.ndarray, shape (n + 1, 2)
        What is added to the plant inputs: the input disturbance, plus the input noise when
        the scenario has some.
    d_out, noise, input_noise : numpy.ndarray, shape (n + 1, 2)
        Output disturbance, measurement noise, input noise (:func:`input_noise`; zeros when off).
    """

    def __init__(self, plant: TITOPlant, decoupler: Decoupler | None = None, scenario: TITOScenario | None = None):
        sc = TITOScenario() if scenario is None else scenario
        if not isinstance(sc, TITOScenario):
            raise ConfigError(f"scenario: must be a TITOScenario, got {type(sc).__name__}")
        if not isinstance(plant, TITOPlant):
            raise ConfigError(f"plant: must be a TITOPlant, got {type(plant).__name__}")
        self.scenario = sc
        dt = sc.dt
        self.plant = vary_plant(plant, sc.variation, sc.vary) if sc.variation else plant
        plant_blocks, dec_blocks = [], []
        rounding = 0.0
        for i in (1, 2):
            for j in (1, 2):
                e = self.plant.element(i, j)
                Ad, Bd, C, D = discretise_rational(_poly(e.K, e.leads), _poly(1.0, e.lags), dt)
                nd, err = _delay_samples(f"plant g{i}{j}", e.L, dt)
                if nd == 0 and D != 0.0:
                    raise ConfigError(f"plant g{i}{j}: biproper element without dead time closes an algebraic "
                                      f"loop; give it L >= dt or a strictly proper rational part")
                rounding = max(rounding, err)
                plant_blocks.append((Ad, Bd, C, D, nd))
        for q, (num, den, L) in enumerate(_decoupler_entries(decoupler)):
            Ad, Bd, C, D = discretise_rational(num, den, dt)
            nd, err = _delay_samples(f"decoupler D{q // 2 + 1}{q % 2 + 1}", L, dt)
            rounding = max(rounding, err)
            dec_blocks.append((Ad, Bd, C, D, nd))
        self.delay_rounding = rounding
        # Controllers have at most two states (a PID with its filter).
        self._m = max(2, max(b[0].shape[0] for b in plant_blocks + dec_blocks))
        nb, m = _k.N_BLOCKS, self._m
        self._A = np.zeros((nb, m, m))
        self._B = np.zeros((nb, m))
        self._C = np.zeros((nb, m))
        self._D = np.zeros(nb)
        self._ns = np.zeros(nb, dtype=np.int64)
        self._nd = np.zeros(nb, dtype=np.int64)
        for b, block in zip(list(range(_k.PLANT0, _k.PLANT0 + 4)) + list(range(_k.DEC0, _k.DEC0 + 4)),
                            plant_blocks + dec_blocks):
            self._set_block(b, *block)
        t = sc.time()
        self.t = t
        self.r = np.ascontiguousarray(np.column_stack([_step_signal(t, sc.setpoints[0]),
                                                       _step_signal(t, sc.setpoints[1])]))
        ti, mi = sc.input_disturbance
        to, mo = sc.output_disturbance
        on_i = (t >= ti - 1e-9).astype(np.float64)
        on_o = (t >= to - 1e-9).astype(np.float64)
        self.d_in = np.column_stack([on_i * mi[0], on_i * mi[1]])
        self.d_out = np.column_stack([on_o * mo[0], on_o * mo[1]])
        self.noise = measurement_noise(sc)
        # Input noise enters where the input disturbance does: the kernel gets their sum. Without
        # it, d_in is left untouched (the simulation is bit for bit the one before the key existed).
        self.input_noise = input_noise(sc)
        if sc.has_input_noise:
            self.d_in = self.d_in + self.input_noise

    def _set_block(self, b, Ad, Bd, C, D, nd):
        k = Ad.shape[0]
        self._A[b] = 0.0
        self._B[b] = 0.0
        self._C[b] = 0.0
        self._A[b, :k, :k] = Ad
        self._B[b, :k] = Bd
        self._C[b, :k] = C
        self._D[b] = D
        self._ns[b] = k
        self._nd[b] = nd

    def arrays(self, controllers):
        """Run the loop for ``controllers`` (a pair of PIController / PIDController).

        Returns
        -------
        status : str
            ``"ok"`` or ``"diverged"``.
        y, ym, u, v : numpy.ndarray, shape (n + 1, 2)
            See :func:`simulate_tito`.
        """
        if isinstance(controllers, (str, bytes)) or not hasattr(controllers, "__len__") or len(controllers) != 2:
            raise ConfigError("controllers: must be a pair (c1, c2) of PIController / PIDController")
        for i, c in enumerate(controllers):
            Ad, Bd, C, D = discretise_rational(*controller_tf(c, i + 1), self.scenario.dt)
            self._set_block(_k.CTRL0 + i, Ad, Bd, C, D, 0)
        n1 = self.t.size
        x = np.zeros((_k.N_BLOCKS, self._m))
        buf = np.zeros((_k.N_BLOCKS, int(self._nd.max()) + 1))
        xt = np.zeros(self._m)
        y = np.empty((n1, 2))
        ym = np.empty((n1, 2))
        u = np.empty((n1, 2))
        v = np.empty((n1, 2))
        status = _k.simulate_tito(self._A, self._B, self._C, self._D, self._ns, self._nd, self.r, self.d_in,
                                  self.d_out, self.noise, x, buf, xt, y, ym, u, v)
        return ("ok" if status == _k.STATUS_OK else "diverged"), y, ym, u, v

    def run(self, controllers) -> pd.DataFrame:
        """The record of :func:`simulate_tito` for ``controllers``."""
        status, y, ym, u, v = self.arrays(controllers)
        r, t = self.r, self.t
        df = pd.DataFrame({"t": t, "r1": r[:, 0], "r2": r[:, 1], "y1": y[:, 0], "y2": y[:, 1],
                           "ym1": ym[:, 0], "ym2": ym[:, 1], "u1": u[:, 0], "u2": u[:, 1],
                           "v1": v[:, 0], "v2": v[:, 1]})
        df.attrs["status"] = status
        df.attrs["delay_rounding"] = self.delay_rounding
        df.attrs["plant"] = self.plant
        return df


def simulate_tito(plant: TITOPlant, controllers, decoupler: Decoupler | None = None,
                  scenario: TITOScenario | None = None) -> pd.DataFrame:
    """Simulate the closed loop; see the module docstring for the structure and discretisation.

    Parameters
    ----------
    plant : TITOPlant
        Nominal plant (``scenario.variation`` is applied to it).
    controllers : pair of PIController / PIDController
        Loop controllers ``c1`` (e1 -> v1) and ``c2`` (e2 -> v2).
    decoupler : Decoupler or None
        ``None`` means ``D = I`` (plain decentralised control).
    scenario : TITOScenario, default ``TITOScenario()``

    Returns
    -------
    DataFrame with columns ``t, r1, r2, y1, y2, ym1, ym2, u1, u2, v1, v2`` (``y``: plant output
    plus output disturbance; ``ym``: ``y`` plus measurement noise; ``u``: decoupler output, before
    the input disturbance and the input noise; ``v``: controller outputs). ``attrs``: ``status`` ("ok" / "diverged"),
    ``delay_rounding`` (largest ``|round(L/dt) dt - L|`` in s), ``plant`` (the simulated plant).
    """
    if isinstance(controllers, (str, bytes)) or not hasattr(controllers, "__len__") or len(controllers) != 2:
        raise ConfigError("controllers: must be a pair (c1, c2) of PIController / PIDController")
    check_sampling(TITOScenario() if scenario is None else scenario, controllers)
    return TITOSimulator(plant, decoupler, scenario).run(controllers)


# --------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------


def _window_integrals(t, e, t0, t1):
    sel = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
    tw, ew = t[sel], e[sel]
    if tw.size < 2:
        return math.nan, math.nan, math.nan, math.nan
    ae = np.abs(ew)
    tau = tw - tw[0]
    iae = float(np.trapezoid(ae, tw))
    ise = float(np.trapezoid(ew * ew, tw))
    itae = float(np.trapezoid(tau * ae, tw))
    return iae, ise, itae, (tw, ae)


def loop_metrics(df: pd.DataFrame, windows: dict | None = None, *, band_pct: float = 2.0) -> pd.DataFrame:
    """Per-loop performance of a :func:`simulate_tito` record.

    Parameters
    ----------
    df : DataFrame from :func:`simulate_tito`.
    windows : mapping name -> (t0, t1)
        Default ``{"servo": (0, 500), "regulatory": (500, t_end)}`` (paper 000's input disturbance
        at 500 s). Each window gets ``IAE_<name>``, ``ISE_<name>``, ``ITAE_<name>`` (trapezoid rule
        on the samples, ITAE with time measured from ``t0``) and ``ts_<name>``.
    band_pct : float
        Settling band, in percent of the largest ``|r_i|`` of the record (of 1 if ``r_i`` is 0
        throughout).

    The error is ``e_i = r_i - y_i`` (noise-free output). ``ts_<name>`` is the time from ``t0`` to
    the first sample after the last one in the window with ``|e_i|`` outside the band (0 if it
    never leaves, ``inf`` if it is outside at ``t1``). Whole-record columns: ``max_abs_u``
    (max ``|u_i|``), ``rms_e`` (root mean square of ``e_i`` over the samples) and ``tv_u``
    (total variation ``sum |u_i[k+1] - u_i[k]|``).

    Returns
    -------
    pandas.DataFrame
        Indexed by loop (1, 2).
    """
    t = df["t"].to_numpy()
    if windows is None:
        windows = {"servo": (0.0, min(500.0, t[-1])), "regulatory": (min(500.0, t[-1]), t[-1])}
    if not isinstance(windows, dict):
        raise ConfigError(f"loop_metrics: windows must be a mapping name -> (t0, t1), got {windows!r}")
    if not (math.isfinite(band_pct) and band_pct > 0):
        raise ConfigError(f"loop_metrics: band_pct must be > 0, got {band_pct!r}")
    rows = []
    for i in (1, 2):
        r = df[f"r{i}"].to_numpy()
        e = r - df[f"y{i}"].to_numpy()
        u = df[f"u{i}"].to_numpy()
        scale = float(np.max(np.abs(r)))
        band = band_pct / 100.0 * (scale if scale > 0 else 1.0)
        row = {"loop": i}
        for name, win in windows.items():
            try:
                t0, t1 = (float(v) for v in win)
            except (TypeError, ValueError):
                raise ConfigError(f"loop_metrics: window {name!r} must be (t0, t1), got {win!r}") from None
            if not t1 > t0:
                raise ConfigError(f"loop_metrics: window {name!r} needs t1 > t0, got {win!r}")
            iae, ise, itae, data = _window_integrals(t, e, t0, t1)
            ts = math.nan
            if not isinstance(data, float):
                tw, ae = data
                out = np.flatnonzero(ae > band)
                if out.size == 0:
                    ts = 0.0
                elif out[-1] == tw.size - 1:
                    ts = math.inf
                else:
                    ts = float(tw[out[-1] + 1] - tw[0])
            row.update({f"IAE_{name}": iae, f"ISE_{name}": ise, f"ITAE_{name}": itae, f"ts_{name}": ts})
        row["max_abs_u"] = float(np.max(np.abs(u)))
        row["rms_e"] = float(np.sqrt(np.mean(e * e)))
        row["tv_u"] = float(np.sum(np.abs(np.diff(u))))
        rows.append(row)
    return pd.DataFrame(rows).set_index("loop")
