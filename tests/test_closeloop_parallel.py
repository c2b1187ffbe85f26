"""Independent replays on several processes: same results, in order, counted, errors raised."""
from __future__ import annotations

import numpy as np
import pytest

from ssamb.closeloop.estimate import EstimateSettings, Problem, map_fit
from ssamb.closeloop.parallel import available, pmap

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


def test_replayer_counts_the_childrens_simulations():
    from ssamb.closeloop.replay import Replayer

    class Rec:
        n = 10

    rp = Replayer({}, Rec(), workers=2)

    def fake(x):
        rp.n_sims += 1
        rp.wall_s += 0.5
        return x + 1
    assert rp.map(fake, [(i,) for i in range(4)]) == [1, 2, 3, 4]
    assert rp.n_sims == 4 and rp.wall_s == pytest.approx(2.0)
