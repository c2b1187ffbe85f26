r"""Discrete-time state-space simulation, compiled.

.. math::

    x_{i+1} = A x_i + B u_i, \qquad y_i = C x_i + D u_i, \qquad x_0 \text{ given},

the recursion of :func:`scipy.signal.dlsim` (and of SIPPY's ``SS_lsim_process_form``). Both
run it as a Python loop that calls ``np.dot`` four times per sample: on the chain's records
(50 000 samples at the 83.3 kHz controller rate, models of 3 to 40 states) the interpreter's
overhead per call, not the arithmetic, sets the time. Here it is one numba loop (compiled once
per process, cached on disk). The sums run in another order than BLAS's, so results agree with
those loops to round-off, not bit for bit.
"""
from __future__ import annotations

import numpy as np

_KERNEL: dict = {}


def process_kernel():
    """The compiled recursion: ``(A, B, C, D, u (m, L), x0 (n,)) -> x (n, L), y (l, L)``, every
    argument a C-contiguous float64 array. No temporaries inside the time loop."""
    if "process" not in _KERNEL:
        import numba  # imported where needed: numba's import costs a job that never simulates

        @numba.njit(cache=True)
        def process(A, B, C, D, u, x0):  # pragma: no cover - compiled
            n = A.shape[0]
            m = B.shape[1]
            l_ = C.shape[0]
            L = u.shape[1]
            x = np.zeros((n, L))
            y = np.zeros((l_, L))
            for j in range(n):
                x[j, 0] = x0[j]
            for i in range(L):
                if i > 0:
                    for j in range(n):
                        acc = 0.0
                        for k in range(n):
                            acc += A[j, k] * x[k, i - 1]
                        for k in range(m):
                            acc += B[j, k] * u[k, i - 1]
                        x[j, i] = acc
                for r in range(l_):
                    acc = 0.0
                    for k in range(n):
                        acc += C[r, k] * x[k, i]
                    for k in range(m):
                        acc += D[r, k] * u[k, i]
                    y[r, i] = acc
            return x, y

        _KERNEL["process"] = process
    return _KERNEL["process"]


def dlsim(A, B, C, D, u, x0=None) -> tuple[np.ndarray, np.ndarray]:
    """States and outputs of a discrete-time state-space model driven by ``u``.

    Parameters
    ----------
    A, B, C, D : array_like
        (n, n), (n, m), (l, n), (l, m).
    u : array_like
        (N, m) inputs, one row per sample (a 1-D array is one input).
    x0 : array_like, optional
        (n,) initial state (zero if omitted).

    Returns
    -------
    x : ndarray
        (N, n) states, ``x[0] = x0``.
    y : ndarray
        (N, l) outputs.

    Examples
    --------
    >>> import numpy as np
    >>> x, y = dlsim([[0.5]], [[1.0]], [[2.0]], [[0.0]], np.ones(3))
    >>> y.ravel().tolist()
    [0.0, 2.0, 3.0]
    """
    f64 = lambda a: np.ascontiguousarray(np.atleast_2d(np.asarray(a, dtype=np.float64)))  # noqa: E731
    A, B, C, D = (f64(M) for M in (A, B, C, D))
    u = np.asarray(u, dtype=np.float64)
    u = u[:, None] if u.ndim == 1 else u
    n = A.shape[0] if A.size else 0
    N = u.shape[0]
    if n == 0:  # a static gain
        return np.zeros((N, 0)), u @ D.T
    x0 = np.zeros(n) if x0 is None else np.ascontiguousarray(np.asarray(x0, dtype=np.float64).reshape(n))
    if N == 0:
        return np.zeros((0, n)), np.zeros((0, C.shape[0]))
    x, y = process_kernel()(A, B, C, D, np.ascontiguousarray(u.T), x0)
    return x.T.copy(), y.T.copy()
