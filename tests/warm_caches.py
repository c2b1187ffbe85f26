"""Compile the numba code of the ball's simulator, the mu engine, the linear simulation and the
identification once, into numba's on-disk cache (``__pycache__`` beside each module).

``python tests/warm_caches.py``: tests/conftest.py starts it in the background when a test
session starts, beside the AMB simulator's own compilation. On a fresh clone the session's
workers and the smoke workflow's jobs would otherwise meet these functions uncompiled, and two
processes that start together (two mu jobs of the workflow, a test beside a job) each compile
them. Every call is a small one with the argument types of the real ones, so that the cached
machine code is the code they load.
"""
from __future__ import annotations

import numpy as np


def maglev1d() -> None:
    """The ball's simulator and its controller over a few samples of the default configuration."""
    from ssamb.maglev1d import controller, physics
    from ssamb.maglev1d.config import load_config

    cfg = load_config()
    n = 8
    yd = np.full(n, 5.0e-3)
    physics.simulate(physics.knobs_of(cfg), controller.gains_of(cfg), yd, [(0, n)], np.zeros((1, 7)),
                     np.zeros((3, n)))
    controller.run(yd, np.zeros(n), yd, controller.gains_of(cfg))


def mu() -> None:
    """Both bounds of mu for a complex matrix with real, complex and full blocks."""
    from ssamb.mu import mussv

    rng = np.random.default_rng(0)
    m = rng.standard_normal((4, 4)) + 1j * rng.standard_normal((4, 4))
    mussv(m, [[-1, 0], [1, 0], [2, 2]])


def linear() -> None:
    """The linear simulation (:func:`ssamb.lsim.dlsim`) and the identification's state regressors."""
    from ssamb.identification.model import _state_regressors
    from ssamb.lsim import dlsim

    dlsim([[0.5]], [[1.0]], [[2.0]], [[0.0]], np.ones(3))
    _state_regressors(np.eye(2) * 0.5, np.ones((1, 2)), np.ones((4, 1)))


if __name__ == "__main__":
    import ssamb

    ssamb.pin_blas_threads()
    for warm in (maglev1d, mu, linear):         # the workflow's first jobs simulate the ball
        warm()
