r"""SIPPY speed-up: compiled replacements of its two Python simulation loops (the same recursion),
and its pseudo-inverses of long data matrices through a QR factorisation (:func:`pinv_qr`)."""
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


def pinv_qr(a, rcond=1e-15):
    r"""Moore-Penrose pseudo-inverse of a long (tall or wide) matrix through its QR factors.

    For :math:`a` of shape (M, N), :math:`M \ge N`: :math:`a = Q R` with :math:`Q` (M, N)
    orthonormal columns and :math:`R` (N, N), so :math:`a^+ = R^+ Q^T` (a wide matrix is the
    transpose of a tall one, :math:`a^+ = ((a^T)^+)^T`). :math:`R` has the singular values of
    :math:`a`, so the same relative cutoff ``rcond`` (:func:`numpy.linalg.pinv`'s default
    1e-15) drops the same ones. SIPPY's data matrices are long (horizons times channels rows,
    tens of thousands of samples as columns): the Householder QR and one product cost about a
    third of the SVD of the long matrix that :func:`numpy.linalg.pinv` computes, with its
    (N, M) singular vectors. Equal to :func:`numpy.linalg.pinv` to round-off; other shapes
    (at most 4:1) go to :func:`numpy.linalg.pinv` itself.
    """
    a = np.asarray(a)
    if a.ndim != 2 or a.dtype.kind != "f" or min(a.shape) == 0 or max(a.shape) < 4 * min(a.shape):
        return np.linalg.pinv(a, rcond)
    if a.shape[0] < a.shape[1]:
        return pinv_qr(a.T, rcond).T
    import scipy.linalg

    q, r = scipy.linalg.qr(a, mode="economic")
    return np.linalg.pinv(r, rcond) @ q.T


def numpy_with_pinv(pinv):
    """A stand-in for the ``numpy`` module whose ``linalg.pinv`` is ``pinv`` (everything else is
    numpy's own): SIPPY's modules call ``np.linalg.pinv`` through their global ``np``."""
    import types

    linalg = types.SimpleNamespace(**{k: getattr(np.linalg, k) for k in dir(np.linalg) if not k.startswith("__")})
    linalg.pinv = pinv
    view = types.SimpleNamespace(**{k: getattr(np, k) for k in dir(np) if not k.startswith("__")})
    view.linalg = linalg
    return view


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
    """Temporarily replace SIPPY's pure-Python state-space simulators by compiled equivalents,
    and its pseudo-inverses by :func:`pinv_qr`.

    SIPPY's PARSIM methods simulate the predictor once per unknown parameter
    (:math:`n m + n l + n` runs of :math:`N` Python iterations: a minute for the 4x4 amplifier
    at N = 40 000). The replacements compute the same recursion (tested against SIPPY's own
    functions) with numba. A pseudo-inverse an enclosing
    :func:`~ssamb.identification.memo.identification_memo` already replaced is left to it (the
    memo computes with :func:`pinv_qr` too, so both paths give the same bits). The patch is
    scoped to the ``with`` block (not thread safe).
    """
    if _jit_kernels() is None:  # pragma: no cover
        yield
        return
    from sippy_unipi import OLSims_methods, Parsim_methods, functionsetSIM

    patches = [(OLSims_methods, "SS_lsim_process_form", _fast_process_form),
               (Parsim_methods, "SS_lsim_process_form", _fast_process_form),
               (Parsim_methods, "SS_lsim_predictor_form", _fast_predictor_form)]
    if OLSims_methods.pinv is np.linalg.pinv:
        patches.append((OLSims_methods, "pinv", pinv_qr))
    view = numpy_with_pinv(pinv_qr)
    patches += [(mod, "np", view) for mod in (OLSims_methods, Parsim_methods, functionsetSIM) if mod.np is np]
    saved = [(mod, name, getattr(mod, name)) for mod, name, _ in patches]
    try:
        for mod, name, fn in patches:
            setattr(mod, name, fn)
        yield
    finally:
        for mod, name, fn in saved:
            setattr(mod, name, fn)
