"""ssamb.lsim: the compiled state-space simulation against scipy.signal.dlsim's recursion."""
from __future__ import annotations

import numpy as np
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from ssamb.lsim import dlsim


@settings(max_examples=30, deadline=None)
@given(n=st.integers(0, 5), m=st.integers(1, 3), l_=st.integers(1, 3), N=st.integers(1, 40),
       seed=st.integers(0, 2**32 - 1))
def test_dlsim_is_scipys_recursion(n, m, l_, N, seed):
    rng = np.random.default_rng(seed)
    A = 0.6 * rng.normal(size=(n, n)) / max(n, 1) ** 0.5
    B, C, D = rng.normal(size=(n, m)), rng.normal(size=(l_, n)), rng.normal(size=(l_, m))
    u, x0 = rng.normal(size=(N, m)), rng.normal(size=n)
    x, y = dlsim(A, B, C, D, u, x0)
    assert x.shape == (N, n) and y.shape == (N, l_)
    if n:
        _, y_ref, x_ref = scipy.signal.dlsim((A, B, C, D, 1.0), u, x0=x0)
        np.testing.assert_allclose(x, np.reshape(x_ref, (N, n)), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(y, np.reshape(y_ref, (N, l_)), rtol=1e-12, atol=1e-12)
    else:
        np.testing.assert_allclose(y, u @ D.T)


def test_first_order_step_response():
    """x+ = a x + u, y = x: the step response is (1 - a^i) / (1 - a)."""
    a = 0.5
    _, y = dlsim([[a]], [[1.0]], [[1.0]], [[0.0]], np.ones(6))
    np.testing.assert_allclose(y.ravel(), (1 - a ** np.arange(6)) / (1 - a))
