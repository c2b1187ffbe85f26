r"""Exact reuse of the work identifications of one data set share (a scoped memo).

One identification stage identifies the same record many times: four SIPPY methods at the
configured order (:func:`~ssamb.identification.selection.compare_methods`), the same method at
fifteen orders (:func:`~ssamb.identification.selection.order_scan`) and a grid of methods,
horizons and stability options for the selection by the assembled loop
(:func:`~ssamb.identification.joint.identify_candidates`). Much of each is the same
computation on the same arrays:

* the operating point (:func:`~ssamb.identification.subspace.arx_equilibrium`) and the input
  excitation (:func:`~ssamb.identification.data.input_excitation`) depend on the data and the
  horizon only;
* the orthogonal projections of SIPPY's subspace step,
  :math:`Z \Pi_{U_f}^{\perp} = Z - Z U_f^T (U_f^T)^{+}`, and the pseudo-inverses behind them
  depend on the data and the horizon, not on the method's weighting nor on the order;
* SIPPY's weighted SVD (``SVD_weighted``) depends on the data, the horizon and the method, not
  on the order or on ``SS_A_stability``.

Inside :func:`identification_memo` each of these is computed once per distinct input and
then returned from memory. Every memoised value is the output of the very call it replaces
(the same function on the same bits), so the results are *bit-identical* to the
computation without the memo (``tests/test_identification_memo.py`` compares the models'
matrices byte for byte). Keys are the arrays' contents (SHA-1 of their bytes, with shape and
dtype), never their identity; memoised arrays are returned read-only, so a caller that
tried to modify one in place would raise rather than corrupt a later result.

The memo is scoped: outside a ``with identification_memo():`` block nothing is kept and
SIPPY is untouched; blocks nest (an inner block reuses the outer memo). The SIPPY patches
are module attributes swapped for the duration of the block (not thread safe, like
:func:`~ssamb.identification.sippy_fast.fast_sippy`). Memory is bounded: least recently
used entries are dropped beyond ``max_bytes``.
"""
from __future__ import annotations

import contextlib
import hashlib
from collections import OrderedDict
from typing import Any, Callable, Iterator

import numpy as np

__all__ = ["identification_memo", "no_memo", "memoised", "active", "array_key", "MAX_BYTES"]

#: default bound of the memo's arrays (bytes); the identify rule asks for 4 GB
MAX_BYTES = 1_500_000_000


def array_key(a: Any) -> tuple:
    """Content key of an array (or of a scalar/str/None/tuple of them)."""
    if isinstance(a, np.ndarray):
        arr = np.ascontiguousarray(a)
        return ("nd", arr.shape, arr.dtype.str, hashlib.sha1(arr.view(np.uint8).reshape(-1)).digest())
    if isinstance(a, (list, tuple)):
        return ("seq", tuple(array_key(v) for v in a))
    if isinstance(a, (int, float, str, bool, type(None), np.integer, np.floating)):
        return ("v", type(a).__name__, a)
    raise TypeError(f"no content key for {type(a).__name__}")


def _nbytes(v: Any) -> int:
    if isinstance(v, np.ndarray):
        return v.nbytes
    if isinstance(v, (list, tuple)):
        return sum(_nbytes(x) for x in v)
    if isinstance(v, dict):
        return sum(_nbytes(x) for x in v.values())
    return 64


def _frozen(v: Any) -> Any:
    """``v`` with every array in it made read-only (the memo hands out the same objects)."""
    if isinstance(v, np.ndarray):
        v.setflags(write=False)
    elif isinstance(v, (list, tuple)):
        for x in v:
            _frozen(x)
    elif isinstance(v, dict):
        for x in v.values():
            _frozen(x)
    return v


class _Memo:
    """Least-recently-used store of computed values keyed by content, bounded in bytes."""

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self.store: OrderedDict = OrderedDict()
        self.sizes: dict = {}
        self.bytes = 0
        self.hits = 0
        self.misses = 0

    def get(self, key, compute: Callable[[], Any]):
        if key in self.store:
            self.store.move_to_end(key)
            self.hits += 1
            return self.store[key]
        self.misses += 1
        value = _frozen(compute())
        size = _nbytes(value)
        if size <= self.max_bytes:
            self.store[key] = value
            self.sizes[key] = size
            self.bytes += size
            while self.bytes > self.max_bytes:
                old, _ = self.store.popitem(last=False)
                self.bytes -= self.sizes.pop(old)
        return value


_ACTIVE: list[_Memo | None] = []


def active() -> _Memo | None:
    """The memo of the enclosing :func:`identification_memo` block (None outside one or inside
    :func:`no_memo`)."""
    return _ACTIVE[-1] if _ACTIVE else None


@contextlib.contextmanager
def no_memo() -> Iterator[None]:
    """Inside the block every computation is done afresh and SIPPY runs unpatched (the
    reference the memo is tested against); blocks of :func:`identification_memo` in it do
    nothing."""
    _ACTIVE.append(None)
    try:
        yield
    finally:
        _ACTIVE.pop()


def memoised(name: str, fn: Callable, *args, **kwargs):
    """``fn(*args, **kwargs)``, from the active memo when there is one (keyed by ``name`` and
    the arguments' contents); a plain call outside :func:`identification_memo`."""
    memo = active()
    if memo is None:
        return fn(*args, **kwargs)
    key = (name, array_key(tuple(args)), array_key(tuple(sorted(kwargs.items()))))
    return memo.get(key, lambda: fn(*args, **kwargs))


def _sippy_patches(memo: _Memo) -> list[tuple[Any, str, Any]]:
    """(module, attribute, replacement) for SIPPY's projection, pseudo-inverse and weighted SVD."""
    from sippy_unipi import OLSims_methods, Parsim_methods, functionsetSIM

    from .sippy_fast import numpy_with_pinv, pinv_qr as pinv

    def pinv_memo(a, *args, **kwargs):
        return memo.get(("pinv", array_key(a), array_key(args), array_key(tuple(sorted(kwargs.items())))),
                        lambda: pinv(a, *args, **kwargs))

    def z_dot_piort(z, X):
        # SIPPY's Z_dot_PIort (z minus its projection on the rows of X), the pseudo-inverse of X^T
        # memoised under the key of X (no transposed copy to hash)
        kx = array_key(X)
        return memo.get(("Z_dot_PIort", array_key(z), kx),
                        lambda: z - np.dot(np.dot(z, X.T), memo.get(("pinv_T", kx), lambda: pinv(X.T))))

    svd_weighted = OLSims_methods.SVD_weighted

    def svd_weighted_memo(y, u, f, l_, weights="N4SID"):
        return memo.get(("SVD_weighted", array_key(y), array_key(u), int(f), int(l_), str(weights)),
                        lambda: svd_weighted(y, u, f, l_, weights))

    def pinv_data(a, *args, **kwargs):
        # PARSIM's pseudo-inverses of wide data matrices (rows: horizons x channels, columns:
        # samples) recur at every order; the tall ones (of the order's simulations) do not
        a = np.asarray(a)
        if a.ndim == 2 and a.shape[0] < a.shape[1]:
            return pinv_memo(a, *args, **kwargs)
        return pinv(a, *args, **kwargs)

    # Parsim_methods calls np.linalg.pinv through its module global `np`: give it a numpy whose
    # linalg.pinv is pinv_data (everything else is numpy's own)
    np_view = numpy_with_pinv(pinv_data)
    return [(functionsetSIM, "Z_dot_PIort", z_dot_piort), (OLSims_methods, "Z_dot_PIort", z_dot_piort),
            (Parsim_methods, "Z_dot_PIort", z_dot_piort), (OLSims_methods, "pinv", pinv_memo),
            (OLSims_methods, "SVD_weighted", svd_weighted_memo), (Parsim_methods, "np", np_view)]


@contextlib.contextmanager
def identification_memo(max_bytes: int = MAX_BYTES) -> Iterator[_Memo]:
    """Memoise, for the duration of the block, the computations identifications of the same
    data share (module docstring); yields the memo (``hits``, ``misses``, ``bytes``).
    Nested blocks reuse the outermost memo (inside :func:`no_memo` they yield None)."""
    if _ACTIVE:
        yield _ACTIVE[-1]
        return
    memo = _Memo(max_bytes)
    patches = _sippy_patches(memo)
    saved = [(mod, name, getattr(mod, name)) for mod, name, _ in patches]
    _ACTIVE.append(memo)
    try:
        for mod, name, fn in patches:
            setattr(mod, name, fn)
        yield memo
    finally:
        for mod, name, fn in saved:
            setattr(mod, name, fn)
        _ACTIVE.pop()
