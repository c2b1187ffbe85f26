"""Independent replays on several processes: same results, in order, counted, errors raised."""
from __future__ import annotations

import numpy as np
import pytest

from ssamb.closeloop.estimate import EstimateSettings, Problem, map_fit
from ssamb.closeloop.parallel import Shared, Workers, available, pmap

pytestmark = pytest.mark.skipif(not available(), reason="no fork here")


def test_pmap_keeps_order_and_closures():
    offset = 7.0
    assert pmap(lambda a, b: a * b + offset, [(i, i + 1) for i in range(9)], workers=2) == \
        [i * (i + 1) + offset for i in range(9)]


def test_pmap_raises_a_childs_error():
    def f(x):
        if x == 3:
            raise ValueError("three")
        return x
    with pytest.raises(ValueError, match="three"):
        pmap(f, [(i,) for i in range(5)], workers=2)


def test_map_fit_on_two_workers_is_the_same_fit():
    """A noisy linear problem fitted with its design on two processes and in turn: identical
    estimate and covariance (every evaluation is seeded)."""
    rng = np.random.default_rng(4)
    B, e = 6.0 * rng.standard_normal((80, 3)), rng.standard_normal(80)

    def evaluate(theta, seed):
        return B @ np.asarray(theta) - e + 0.3 * np.random.default_rng(seed).standard_normal(80)

    def prob(many):
        return Problem(("a", "b", "c"), np.zeros(3), np.array([1.0, 1.0, np.inf]), np.full(3, 0.1), np.full(3, -5.0),
                       np.full(3, 5.0), evaluate, evaluate_many=many)
    one = map_fit(prob(None), EstimateSettings())
    two = map_fit(prob(lambda tasks: pmap(evaluate, tasks, workers=2)), EstimateSettings())
    assert np.array_equal(one.theta, two.theta) and np.array_equal(one.cov, two.cov)
    assert one.evaluations == two.evaluations


def test_workers_serve_batches_in_order_with_a_shared_object():
    """Forked once: two batches with different shared objects, answers in order; the pids show
    the same two workers served both batches."""
    import os

    w = Workers(lambda shared, a: (shared["k"] * a, os.getpid()), 2)
    try:
        one = w.map([(i,) for i in range(7)], Shared({"k": 3}))
        two = w.map([(i,) for i in range(5)], Shared({"k": -1}))
        again = w.map([(i,) for i in range(3)], Shared({"k": 3}))
    finally:
        w.close()
    assert [r[0] for r in one] == [3 * i for i in range(7)]
    assert [r[0] for r in two] == [-i for i in range(5)] and [r[0] for r in again] == [0, 3, 6]
    pids = {r[1] for r in one + two + again}
    assert len(pids) <= 2 and os.getpid() not in pids


def test_workers_raise_a_childs_error_and_stay_usable():
    def f(shared, x):
        if x == 3:
            raise ValueError("three")
        return x
    w = Workers(f, 2)
    try:
        with pytest.raises(ValueError, match="three"):
            w.map([(i,) for i in range(6)])
        assert w.map([(i,) for i in range(3)]) == [0, 1, 2]
    finally:
        w.close()
    with pytest.raises(RuntimeError, match="closed"):
        w.map([(1,), (2,)])


def test_a_dead_worker_is_an_error_not_a_hang():
    import os

    w = Workers(lambda shared, x: os._exit(3) if x == 2 else x, 2)
    with pytest.raises(RuntimeError, match="worker died"):
        w.map([(i,) for i in range(4)])
    assert not w.alive


def test_replayer_counts_the_workers_simulations_and_reuses_them():
    """A fake replay (counters and a pid): the parent's counters hold the workers' simulations;
    the second batch runs on the workers the first forked; close ends them."""
    import os

    from ssamb.closeloop.replay import Replayer

    class Fake(Replayer):
        def run(self, effects=(), n=None, overrides=None, seed=None, cache=True):
            self.n_sims += 1
            self.wall_s += 0.5
            return {"seed": seed, "pid": os.getpid()}

    class Rec:
        n = 10

    rp = Fake({}, Rec(), workers=2)
    first = rp.map_runs([([], None, {}, s) for s in range(4)], post=_seed_plus_one)
    second = rp.map_runs([([], None, {}, s) for s in range(4)])
    assert first == [1, 2, 3, 4] and [r["seed"] for r in second] == [0, 1, 2, 3]
    assert rp.n_sims == 8 and rp.wall_s == pytest.approx(4.0)
    assert os.getpid() not in {r["pid"] for r in second}
    procs = rp._pool[1]._procs
    rp.close()
    assert rp._pool is None and not any(p.is_alive() for p in procs)


def _seed_plus_one(out):
    return out["seed"] + 1


def test_a_result_that_does_not_pickle_is_an_error_naming_it():
    w = Workers(lambda shared, x: (lambda: x), 2)
    try:
        with pytest.raises(RuntimeError, match="could not return its result"):
            w.map([(1,), (2,)])
    finally:
        w.close()
