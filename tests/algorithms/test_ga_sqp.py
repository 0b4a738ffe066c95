"""The real-coded GA (operators pinned to their formulas, elitism, quality) and multistart SQP
(constrained optimum, exact budgets, worker-count independence, per-start details)."""

import numpy as np
import pandas as pd
import pytest
from numerics import assert_exact, assert_same_bits

import heurtune
from heurtune.algorithms import ga
from heurtune.algorithms import sqp_multistart as sqp
from heurtune.core import registry
from heurtune.core.engine import Comparator, SearchSpace

DEB = Comparator("deb")


# -- GA operators ------------------------------------------------------------------------------
def _betaq(u, beta, eta):
    """SBX spread factor from Deb's bounded formula, written out for one scalar."""
    alpha = 2.0 - beta ** (-(eta + 1.0))
    if u <= 1.0 / alpha:
        return (u * alpha) ** (1.0 / (eta + 1.0))
    return (1.0 / (2.0 - u * alpha)) ** (1.0 / (eta + 1.0))


def test_sbx_matches_the_bounded_formula_on_two_variables():
    lower, upper, eta = np.array([0.0, -3.0]), np.array([5.0, 1.0]), 15.0
    p1, p2 = np.array([[3.0, -2.0]]), np.array([[1.0, 0.5]])
    u_beta = np.array([[0.8, 0.3]])  # variable 0: the u > 1/alpha branch; variable 1: u <= 1/alpha
    c1, c2 = ga.sbx(p1, p2, lower, upper, eta, 0.9, u_pair=np.array([0.3]), u_var=np.array([[0.2, 0.5]]),
                    u_beta=u_beta, u_swap=np.array([[0.9, 0.1]]))
    # variable 0: y1 = 1, y2 = 3, no swap; variable 1: y1 = -2, y2 = 0.5, swapped
    b1 = _betaq(0.8, 1 + 2 * (1 - 0) / 2, eta)
    b2 = _betaq(0.8, 1 + 2 * (5 - 3) / 2, eta)
    assert c1[0, 0] == pytest.approx(0.5 * (4 - b1 * 2), rel=1e-14)
    assert c2[0, 0] == pytest.approx(0.5 * (4 + b2 * 2), rel=1e-14)
    b1 = _betaq(0.3, 1 + 2 * (-2 - -3) / 2.5, eta)
    b2 = _betaq(0.3, 1 + 2 * (1 - 0.5) / 2.5, eta)
    assert c2[0, 1] == pytest.approx(0.5 * (-1.5 - b1 * 2.5), rel=1e-14)  # swapped: child 2 gets c1
    assert c1[0, 1] == pytest.approx(0.5 * (-1.5 + b2 * 2.5), rel=1e-14)


def test_sbx_skips_pairs_variables_and_equal_parents():
    lo, hi = np.zeros(2), np.ones(2)
    p1, p2 = np.array([[0.2, 0.4]]), np.array([[0.6, 0.4]])
    draws = dict(u_beta=np.full((1, 2), 0.7), u_swap=np.full((1, 2), 0.9))
    c1, c2 = ga.sbx(p1, p2, lo, hi, 15, 0.9, u_pair=np.array([0.95]), u_var=np.zeros((1, 2)), **draws)
    assert_exact(c1, p1)  # pair not crossed (u_pair > p_c): the parents copied
    assert_exact(c2, p2)
    c1, c2 = ga.sbx(p1, p2, lo, hi, 15, 0.9, u_pair=np.array([0.1]), u_var=np.array([[0.6, 0.1]]), **draws)
    assert_exact(c1, p1)  # variable 0 not recombined, variable 1 has equal parents: copied
    assert_exact(c2, p2)


def test_sbx_far_from_the_bounds_is_the_classic_operator():
    """With distant faces the bounded form tends to Deb & Agrawal's unbounded SBX."""
    eta, rng = 15.0, np.random.default_rng(0)
    p1, p2 = rng.random((50, 3)), rng.random((50, 3))
    u = rng.random((50, 3))
    c1, c2 = ga.sbx(p1, p2, np.full(3, -1e9), np.full(3, 1e9), eta, 1.0, np.zeros(50), np.zeros((50, 3)),
                    u, np.ones((50, 3)))
    bq = np.where(u <= 0.5, (2 * u) ** (1 / (eta + 1)), (1 / (2 * (1 - u))) ** (1 / (eta + 1)))
    y1, y2 = np.minimum(p1, p2), np.maximum(p1, p2)
    np.testing.assert_allclose(c1, 0.5 * ((1 + bq) * y1 + (1 - bq) * y2), atol=1e-6)
    np.testing.assert_allclose(c2, 0.5 * ((1 - bq) * y1 + (1 + bq) * y2), atol=1e-6)
    np.testing.assert_allclose(c1 + c2, p1 + p2, atol=1e-6)  # the parents' mean is kept


def test_sbx_and_mutation_children_stay_in_the_box():
    rng = np.random.default_rng(1)
    lo, hi = np.array([-1.0, 0.0, 2.0]), np.array([1.0, 1e-3, 2.0])  # one zero-width variable
    P = lo + rng.random((400, 3)) * (hi - lo)
    P[:50, 0] = lo[0]
    P[50:100, 0] = hi[0]
    c1, c2 = ga.sbx(P[:200], P[200:], lo, hi, 2.0, 1.0, rng.random(200), rng.random((200, 3)),
                    rng.random((200, 3)), rng.random((200, 3)))
    M = ga.polynomial_mutation(np.vstack([c1, c2]), lo, hi, 1.0, 1.0, rng.random((400, 3)), rng.random((400, 3)))
    for X in (c1, c2, M):
        assert np.all(X >= lo) and np.all(X <= hi)
    assert np.all(M[:, 2] == 2.0)  # exact: a zero-width variable stays on its bound


def test_polynomial_mutation_matches_the_bounded_formula():
    lo, hi, eta = np.array([0.0, -2.0]), np.array([4.0, 2.0]), 20.0
    X = np.array([[1.0, 1.5]])
    Y = ga.polynomial_mutation(X, lo, hi, eta, 0.5, u_do=np.array([[0.1, 0.5]]), u_delta=np.array([[0.2, 0.9]]))
    d1 = (1.0 - 0.0) / 4.0
    dq = (2 * 0.2 + (1 - 2 * 0.2) * (1 - d1) ** (eta + 1)) ** (1 / (eta + 1)) - 1
    assert Y[0, 0] == pytest.approx(1.0 + dq * 4.0, rel=1e-14)
    d2 = (2.0 - 1.5) / 4.0
    dq = 1 - (2 * (1 - 0.9) + 2 * (0.9 - 0.5) * (1 - d2) ** (eta + 1)) ** (1 / (eta + 1))
    assert Y[0, 1] == pytest.approx(1.5 + dq * 4.0, rel=1e-14)
    Y = ga.polynomial_mutation(X, lo, hi, eta, 0.05, u_do=np.array([[0.1, 0.06]]), u_delta=np.array([[0.2, 0.9]]))
    assert_exact(Y, X)  # neither variable drawn for mutation: copied


def test_tournament_follows_debs_rules():
    f = np.array([5.0, 1.0, 0.0, 3.0, 2.0, 2.0])
    v = np.array([0.0, 0.0, 0.5, 0.2, 0.0, 0.0])
    a = np.array([0, 2, 3, 1, 4, 4])
    b = np.array([1, 0, 2, 3, 5, 5])
    coin = np.array([0.9, 0.9, 0.9, 0.0, 0.1, 0.9])
    won = ga.tournament(f, v, a, b, coin, DEB)
    # feasible by f; feasible beats infeasible with better f; infeasible by violation;
    # feasible beats infeasible (a wins on its own); a tie goes to the coin
    assert_exact(won, [1, 0, 3, 1, 4, 5])
    won = ga.tournament(f, v, a, b, coin, Comparator("penalty", penalty=10.0))
    # merits 5, 1, 5, 5, 2, 2: ties 2 vs 0 and 3 vs 2 go to the coin (b)
    assert_exact(won, [1, 0, 2, 1, 4, 5])


def test_ga_settings_are_validated():
    with pytest.raises(heurtune.ConfigError, match="p_c must lie in"):
        registry.make_settings("ga", {"p_c": 1.5})
    with pytest.raises(heurtune.ConfigError, match="n must be >= 2"):
        registry.make_settings("ga", {"n": 1})


# -- GA as a whole --------------------------------------------------------------------------------
def test_ga_is_elitist_under_debs_rules():
    """Drive ask/tell by hand: the population's best never gets worse, on a constrained problem."""
    space = SearchSpace(np.full(3, -2.0), np.full(3, 2.0))
    opt = ga.GeneticAlgorithm(space, ga.GASettings(n=8, n_offspring=6), np.random.default_rng(3), DEB)

    def evaluate(X):
        f = (X ** 2).sum(axis=1) + 0.3 * np.sin(7 * X[:, 0])
        v = np.maximum(0.5 - X[:, 1] - X[:, 2], 0.0)
        return f, v

    best = None
    for _ in range(60):
        X = opt.ask()
        assert np.all(X >= space.lower) and np.all(X <= space.upper)
        opt.tell(X, *evaluate(X))
        i = DEB.best(opt.f, opt.v)
        if best is not None:
            assert not DEB.better(best[0], best[1], opt.f[i], opt.v[i])
        best = (opt.f[i], opt.v[i])
        assert len(opt.f) == 8
    assert best[1] == 0.0  # ends feasible (exact: max(..., 0.0) gives the literal 0)


def test_ga_on_the_shifted_sphere():
    """10-D sphere shifted to 1.3 on [-5, 5]^10, n = 100, 20000 evaluations: f < 1e-4 for every
    seed (measured over seeds 0-9: median 9e-6, worst 4.7e-5; pymoo 0.6.2's GA, same budget:
    median 1.0e-5, worst 5.1e-5)."""
    def shifted(X):
        return ((X - 1.3) ** 2).sum(axis=1)

    for seed in range(3):
        res = heurtune.minimize(shifted, [-5] * 10, [5] * 10, "ga", max_evals=20000, seed=seed)
        assert res.n_evals == 20000 and res.f < 1e-4
        assert np.all(res.history.best_f.diff().iloc[1:] <= 0)


# -- multistart SQP ---------------------------------------------------------------------------------
def _disk(X):
    """min x0^2 + x1^2 subject to x0 + x1 >= 1: optimum (0.5, 0.5), f = 0.5."""
    return (X ** 2).sum(axis=1), (1.0 - X[:, 0] - X[:, 1])[:, None]


def test_sqp_finds_the_constrained_optimum_from_few_starts():
    res = heurtune.minimize(_disk, [-2, -2], [2, 2], "sqp_multistart", seed=0, settings=dict(starts=5))
    assert res.stop_reason == "finished" and res.feasible
    np.testing.assert_allclose(res.x, [0.5, 0.5], atol=1e-5)
    assert res.f == pytest.approx(0.5, abs=1e-5)
    d = res.details
    assert isinstance(d, pd.DataFrame) and len(d) == 5 and list(d.start) == list(range(5))
    assert list(d.columns) == ["start", "round", "cap", "x0", "x", "f", "violation", "nfev", "nit", "success",
                               "message"]
    assert d.success.all() and d.nfev.sum() == res.n_evals
    for x0 in d.x0:
        assert np.all(np.abs(x0) <= 2)


def test_sqp_budget_is_exact_caps_are_even_and_rounds_fill_it():
    calls = []

    def counted(X):
        calls.append(len(X))
        return _disk(X)

    res = heurtune.minimize(counted, [-2, -2], [2, 2], "sqp_multistart", seed=1, max_evals=100,
                            settings=dict(starts=3, max_iter=50))
    d = res.details
    assert sum(calls) == res.n_evals == 100 and res.stop_reason == "max_evals"
    assert list(d.cap[d["round"] == 0]) == [34, 33, 33]
    assert d.nfev.sum() == 100 and np.all(d.nfev <= d.cap)
    assert d["round"].max() >= 1  # the starts converged early; later rounds used the rest
    # a start cut at its cap still reports its best evaluated point
    tight = heurtune.minimize(_disk, [-2, -2], [2, 2], "sqp_multistart", seed=1, max_evals=4,
                              settings=dict(starts=2))
    assert list(tight.details.message) == ["evaluation cap reached"] * 2
    assert np.isfinite(tight.details.f).all() and tight.n_evals == 4
    # no budget filling: one round, leftover unused
    res = heurtune.minimize(_disk, [-2, -2], [2, 2], "sqp_multistart", seed=1, max_evals=10_000,
                            settings=dict(starts=3, fill_budget=False))
    assert len(res.details) == 3 and res.n_evals < 10_000 and res.stop_reason == "finished"


def test_sqp_uniform_sampling_and_settings():
    res = heurtune.minimize(_disk, [-2, -2], [2, 2], "sqp_multistart", seed=2,
                            settings=dict(starts=3, sampling="uniform", fd_step=1e-7))
    np.testing.assert_allclose(res.x, [0.5, 0.5], atol=1e-5)
    with pytest.raises(heurtune.ConfigError, match="sampling must be one of"):
        registry.make_settings("sqp_multistart", {"sampling": "sobol"})
    assert sqp.even_caps(10, 4) == [3, 3, 2, 2] and sum(sqp.even_caps(7, 7)) == 7


def test_sqp_is_bit_identical_with_one_and_two_workers():
    def wavy(X):  # nested, so that it is pickled by value for the workers
        f = ((X - 0.2) ** 2).sum(axis=1) + 0.1 * np.cos(5 * X).sum(axis=1)
        return f, (X[:, 0] ** 2 - X[:, 1] - 0.5)[:, None]

    lo, hi = [-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]
    # default batch: results and history must not depend on the workers
    kw = dict(seed=7, max_evals=300, settings=dict(starts=6, max_iter=20))
    a = heurtune.minimize(wavy, lo, hi, "sqp_multistart", n_jobs=1, **kw)
    b = heurtune.minimize(wavy, lo, hi, "sqp_multistart", n_jobs=2, **kw)
    assert a.n_evals == b.n_evals == 300
    assert_same_bits(a.x, b.x, because="workers")
    assert_same_bits([a.f, a.violation], [b.f, b.violation], because="workers")
    assert_same_bits(a.details, b.details, because="workers")
    # another batch size: the history is the same too
    kw["settings"] = dict(starts=6, max_iter=20, batch=4)
    a = heurtune.minimize(wavy, lo, hi, "sqp_multistart", n_jobs=1, **kw)
    b = heurtune.minimize(wavy, lo, hi, "sqp_multistart", n_jobs=2, **kw)
    assert_same_bits(a.details, b.details, because="workers")
    cols = ["epoch", "n_evals", "best_f", "best_violation", "mean_f", "sd_f", "feasible_fraction"]
    assert_same_bits(a.history[cols], b.history[cols], because="workers")


@pytest.mark.skipif(not sqp._slsqp_takes_workers(), reason="this scipy's SLSQP takes no map for its differences")
@pytest.mark.parametrize("max_evals", [None, 457])
def test_sqp_batched_differences_change_nothing_but_the_calls(monkeypatch, max_evals):
    rows = []

    def wavy(X):
        rows.append(len(X))
        f = ((X - 0.2) ** 2).sum(axis=1) + 0.1 * np.cos(5 * X).sum(axis=1)
        f[X[:, 0] > 0.9] = np.nan  # a failed corner: NaN objective
        return f, (X[:, 0] ** 2 - X[:, 1] - 0.5)[:, None]

    lo, hi = [-1.0] * 5, [1.0] * 5
    kw = dict(seed=3, max_evals=max_evals, settings=dict(starts=7, max_iter=30, batch=3))
    batched = heurtune.minimize(wavy, lo, hi, "sqp_multistart", **kw)
    batched_rows, rows[:] = list(rows), []
    monkeypatch.setattr(sqp, "_slsqp_takes_workers", lambda: False)
    single = heurtune.minimize(wavy, lo, hi, "sqp_multistart", **kw)
    assert set(rows) == {1} and max(batched_rows) == 5  # a gradient's five points in one call
    # the same evaluations (none wasted), counts, caps, best points and history
    assert sum(batched_rows) == sum(rows) == batched.n_evals == single.n_evals
    if max_evals is not None:
        assert batched.n_evals == max_evals
        assert (batched.details.message == "evaluation cap reached").any()  # caps cut gradients
    # a row of wavy is computed alike alone or among the five rows of a gradient (element-wise numpy,
    # a sum along each row), and SLSQP gets the same numbers either way; wall_time_s is a clock reading
    assert_same_bits(batched.details, single.details, because="shared kernel")
    assert_same_bits(batched.x, single.x, because="shared kernel")
    assert_same_bits([batched.f, batched.violation], [single.f, single.violation], because="shared kernel")
    assert_same_bits(batched.history.drop(columns="wall_time_s"), single.history.drop(columns="wall_time_s"),
                     because="shared kernel")


def test_sqp_max_epochs_counts_batches():
    res = heurtune.minimize(_disk, [-2, -2], [2, 2], "sqp_multistart", seed=0, max_epochs=2,
                            settings=dict(starts=20, batch=3))
    assert res.stop_reason == "max_epochs" and len(res.details) == 9 and list(res.history.epoch) == [0, 1, 2]


class _Snapshots(heurtune.core.engine.Checkpoint):
    """An in-memory checkpoint: starts from ``records``, keeps every saved state."""

    def __init__(self, records=()):
        self.records = [dict(r) for r in records]
        self.saves = []

    def load(self):
        return [dict(r) for r in self.records]

    def save(self, records):
        self.saves.append([dict(r) for r in records])


def _sqp_run(fun, checkpoint, n_jobs=1, **kw):
    from heurtune.core.engine import run
    from heurtune.core.evaluator import Evaluator

    space = SearchSpace(np.full(3, -1.0), np.full(3, 1.0))
    with Evaluator(fun, n_jobs=n_jobs) as ev:
        return run("sqp_multistart", ev, space, seed=5, checkpoint=checkpoint, **kw)


def _wavy_fun():
    def wavy(X):  # nested, so that it is pickled by value for the workers
        f = ((X - 0.2) ** 2).sum(axis=1) + 0.1 * np.cos(5 * X).sum(axis=1)
        return f, (X[:, 0] ** 2 - X[:, 1] - 0.5)[:, None]
    return wavy


@pytest.mark.parametrize("budget", [260, None])
@pytest.mark.parametrize("n_jobs", [1, 2])
def test_sqp_resumes_from_its_checkpoint_without_resolving(n_jobs, budget):
    """Each finished start is saved at once; a rerun from a partial checkpoint solves only the
    other starts and ends exactly like the uninterrupted run (caps of a budget included)."""
    wavy = _wavy_fun()
    kw = dict(max_evals=budget, settings=dict(starts=7, max_iter=15, batch=3))
    whole_ck = _Snapshots()
    whole = _sqp_run(wavy, whole_ck, n_jobs, **kw)
    saves = whole_ck.saves
    assert [len(s) for s in saves] == list(range(1, len(whole.details) + 1))  # one save per start
    assert [r["start"] for r in saves[-1]] == list(whole.details.start)
    partial = saves[4]  # the first 5 starts to end (in order with one worker: round 0, two of round 1)
    calls = []

    def counted(X):
        calls.append(len(X))
        return wavy(X)

    resumed_ck = _Snapshots(partial)
    resumed = _sqp_run(counted if n_jobs == 1 else wavy, resumed_ck, n_jobs, **kw)
    if n_jobs == 1:
        assert sum(calls) == whole.n_evals - sum(r["nfev"] for r in partial)
    assert {r["start"] for r in resumed_ck.saves[0]} > {r["start"] for r in partial}
    assert resumed.n_evals == whole.n_evals and resumed.stop_reason == whole.stop_reason
    assert_same_bits(resumed.f, whole.f, because="resume")
    assert_same_bits(resumed.x, whole.x, because="resume")
    assert_same_bits(resumed.g, whole.g, because="resume")
    assert_same_bits(resumed.details, whole.details, because="resume")
    cols = ["epoch", "n_evals", "best_f", "best_violation", "mean_f", "sd_f", "feasible_fraction"]
    assert_same_bits(resumed.history[cols], whole.history[cols], because="resume")


@pytest.mark.parametrize("n_jobs", [1, 2])
def test_sqp_without_a_budget_hands_out_every_start_and_closes_rounds_in_order(n_jobs):
    """Without a budget every start goes to the workers at once: the run must equal one that
    goes round by round (a budget it never reaches), and a stop after a round must keep
    exactly the rounds before it."""
    wavy = _wavy_fun()
    settings = dict(starts=8, max_iter=15, batch=3)
    ahead = _sqp_run(wavy, _Snapshots(), n_jobs, settings=settings)
    by_round = _sqp_run(wavy, _Snapshots(), n_jobs, max_evals=10**6, settings=dict(settings, fill_budget=False))
    assert ahead.details["cap"].isna().all() and by_round.details["cap"].notna().all()
    assert list(ahead.details["round"]) == [0, 0, 0, 1, 1, 1, 2, 2]
    # each start is solved whole by the same code, whenever it is handed out
    assert_same_bits(ahead.details.drop(columns="cap"), by_round.details.drop(columns="cap"), because="workers")
    cols = ["epoch", "n_evals", "best_f", "best_violation", "mean_f", "sd_f", "feasible_fraction"]
    assert_same_bits(ahead.history[cols], by_round.history[cols], because="workers")
    assert_same_bits(ahead.f, by_round.f, because="workers")
    assert ahead.n_evals == by_round.n_evals
    stopped = _sqp_run(wavy, _Snapshots(), n_jobs, max_epochs=1, settings=settings)
    assert stopped.stop_reason == "max_epochs" and list(stopped.history.epoch) == [0, 1]
    assert_same_bits(stopped.details, ahead.details.iloc[:6], because="workers")
    assert stopped.n_evals == ahead.details.nfev.iloc[:6].sum()


def test_sqp_refuses_a_checkpoint_of_another_run():
    ck, wavy = _Snapshots(), _wavy_fun()
    _sqp_run(wavy, ck, settings=dict(starts=2, max_iter=5))
    other = _Snapshots(ck.saves[-1])
    with pytest.raises(heurtune.ConfigError, match="belongs to another run"):
        _sqp_run(wavy, other, max_evals=50, settings=dict(starts=2, max_iter=5))  # caps differ
