"""The acceptance suite's summary (``bench/closeloop_suite.py``) on rows written by hand: the
estimator's seeds (``seed_dependence``) and the seed-by-draw tasks."""
from __future__ import annotations

import argparse

import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def suite():
    return bench_module("closeloop_suite")


def _row(draw: int, seed: int, est: float, se: float, failures=()) -> dict:
    return {"draw": draw, "kind": "sweep", "design_seed": seed, "failures": list(failures),
            "coverage": [{"param": "p", "est": est, "se": se, "truth": 0.0, "z": est / se}]}


def test_the_between_seed_ratio_is_the_seeds_sample_variance_over_the_reported_variance(suite):
    """Draw 0: estimates 0 and 2 with se 1 (sample variance 2, ratio 2); draw 1: 1, 1, 4 with se 3
    (sample variance 3, mean variance 9, ratio 1/3); pooled by degrees of freedom (1 and 2):
    (2 + 2/3) / 3."""
    rows = [_row(0, 0, 0.0, 1.0), _row(0, 1, 2.0, 1.0),
            _row(1, 0, 1.0, 3.0), _row(1, 1, 1.0, 3.0), _row(1, 2, 4.0, 3.0, ["x"])]
    sd = suite.seed_dependence(rows)
    ratio, n, m, _ = sd["per_parameter"]["p"]
    assert ratio == pytest.approx((2.0 + 2.0 / 3.0) / 3.0)
    assert (n, m) == (5, 2)
    assert sd["verdict_differs"] == [1]
    assert (sd["analyses"], sd["draws"], sd["passed"]) == (5, 2, 4)


def test_one_seed_per_draw_has_no_seed_dependence(suite):
    """Without two seeds of one draw there is nothing to compare (None), and a parameter reported in
    one seed only of a draw does not enter the ratio."""
    assert suite.seed_dependence([_row(0, 0, 0.0, 1.0), _row(1, 0, 1.0, 1.0)]) is None
    rows = [_row(0, 0, 0.0, 1.0), {"draw": 0, "kind": "sweep", "design_seed": 1, "failures": [], "coverage": []}]
    assert suite.seed_dependence(rows)["per_parameter"] == {}


def test_each_draw_is_analysed_once_per_design_seed(suite):
    args = argparse.Namespace(kinds="multisine,pulses", start=0, draws=3, null=1, only="1,2",
                              design_seeds="0,5")
    assert suite._tasks(args) == [(1, "pulses", False, 0), (1, "pulses", False, 5),
                                  (2, "multisine", False, 0), (2, "multisine", False, 5)]
    args.design_seeds, args.only = None, None
    assert [t[3] for t in suite._tasks(args)] == [None] * 4


def test_the_ratios_p_value_is_the_chi_square_tail_of_its_degrees_of_freedom(suite):
    """One draw at three seeds, estimates 0, 0, 3 with se 1: sample variance 3, ratio 3 on 2
    degrees of freedom; if the errors covered the seeds' spread, 2 x ratio would be chi-square with 2
    degrees of freedom, whose tail is exp(-x/2): p = exp(-3)."""
    import math

    sd = suite.seed_dependence([_row(0, s, e, 1.0) for s, e in enumerate((0.0, 0.0, 3.0))])
    ratio, n, m, p = sd["per_parameter"]["p"]
    assert (ratio, n, m) == (pytest.approx(3.0), 3, 1)
    assert p == pytest.approx(math.exp(-3.0))
