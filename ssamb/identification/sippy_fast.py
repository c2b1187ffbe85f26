r"""SIPPY speed-up: exact compiled replacements of its two Python simulation loops."""
from __future__ import annotations

import contextlib

import numpy as np

_JIT = {}


def _jit_kernels():
    """The compiled process-form simulator (:func:`ssamb.lsim.process_kernel`; the predictor
    form is the process form with the outputs as extra inputs, :func:`_fast_predictor_form`)."""
    if "process" not in _JIT:
        try:
            from ..lsim import process_kernel

            _JIT["process"] = process_kernel()
        except ImportError:  # pragma: no cover - numba is a dependency; fall back to SIPPY
            return None
    return _JIT


def _f64(a):
    return np.ascontiguousarray(np.atleast_2d(np.asarray(a, dtype=np.float64)))


def _x0vec(x0, n):
    if isinstance(x0, str):
        return np.zeros(n)
    return np.ascontiguousarray(np.asarray(x0, dtype=np.float64).reshape(-1)[:n])


def _fast_process_form(A, B, C, D, u, x0="None"):
    k = _jit_kernels()
    A, B, C, D, u = (_f64(m) for m in (A, B, C, D, u))
    return k["process"](A, B, C, D, u, _x0vec(x0, A.shape[0]))


def _fast_predictor_form(A_K, B_K, C, D, K, y, u, x0="None"):
    """Predictor form x[i+1] = A_K x[i] + B_K u[i] + K y[i], yhat[i] = C x[i] + D u[i]: the
    process form driven by [u; y] with input matrix [B_K, K]; the state has L + 1 columns."""
    k = _jit_kernels()
    A_K, B_K, C, D, K, y, u = (_f64(m) for m in (A_K, B_K, C, D, K, y, u))
    U = np.ascontiguousarray(np.vstack([u, y]))
    B = np.ascontiguousarray(np.hstack([B_K, K]))
    Da = np.ascontiguousarray(np.hstack([D, np.zeros((D.shape[0], K.shape[1]))]))
    x, yh = k["process"](A_K, B, C, Da, U, _x0vec(x0, A_K.shape[0]))
    x_end = A_K @ x[:, -1] + B @ U[:, -1]
    return np.column_stack([x, x_end]), yh


@contextlib.contextmanager
def fast_sippy():
    """Temporarily replace SIPPY's pure-Python state-space simulators by compiled equivalents.

    SIPPY's PARSIM methods simulate the predictor once per unknown parameter
    (:math:`n m + n l + n` runs of :math:`N` Python iterations: a minute for the 4x4 amplifier
    at N = 40 000). The replacements compute the same recursion (tested against SIPPY's own
    functions) with numba. The patch is scoped to the ``with`` block (not thread safe).
    """
    if _jit_kernels() is None:  # pragma: no cover
        yield
        return
    from sippy_unipi import OLSims_methods, Parsim_methods

    saved = [(OLSims_methods, "SS_lsim_process_form", OLSims_methods.SS_lsim_process_form),
             (Parsim_methods, "SS_lsim_process_form", Parsim_methods.SS_lsim_process_form),
             (Parsim_methods, "SS_lsim_predictor_form", Parsim_methods.SS_lsim_predictor_form)]
    try:
        OLSims_methods.SS_lsim_process_form = _fast_process_form
        Parsim_methods.SS_lsim_process_form = _fast_process_form
        Parsim_methods.SS_lsim_predictor_form = _fast_predictor_form
        yield
    finally:
        for mod, name, fn in saved:
            setattr(mod, name, fn)

