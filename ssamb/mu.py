r"""Structured singular value (μ) bounds: the engine.

The structured singular value of a complex matrix :math:`M \in \mathbb{C}^{p\times q}` with
respect to a set :math:`\boldsymbol{\Delta}` of block-diagonal matrices
:math:`\Delta \in \mathbb{C}^{q\times p}` is (Doyle 1982; Packard & Doyle 1993)

.. math::

    \mu_{\boldsymbol\Delta}(M) = \Big(\min\{\bar\sigma(\Delta) : \Delta\in\boldsymbol\Delta,\;
    \det(I_p - M\Delta) = 0\}\Big)^{-1},

and :math:`\mu = 0` when no :math:`\Delta` makes :math:`I - M\Delta` singular.
:func:`mussv` returns an upper and a lower bound, each with its certificate.

Block structure (MATLAB ``mussv`` convention)
---------------------------------------------
``blk`` is a list (or an ``(nblk, 2)`` array) of rows ``[r, c]``:

* ``[-r, 0]``: repeated real scalar :math:`\delta I_r`, :math:`\delta \in \mathbb{R}`;
* ``[r, 0]``: repeated complex scalar :math:`\delta I_r`, :math:`\delta \in \mathbb{C}`;
* ``[r, c]``, ``c > 0``: full complex block :math:`\Delta_i \in \mathbb{C}^{r\times c}`
  (``[1, 1]`` is a single complex scalar).

The blocks are stacked in order, so :math:`\Delta = \mathrm{diag}(\Delta_1, \ldots)` is
:math:`(\sum r_i) \times (\sum c_i)` (a scalar block counts ``c_i = r_i``) and, since
:math:`M\Delta` must be square, **M is** :math:`(\sum c_i) \times (\sum r_i)`: block ``i``
reads the ``r_i`` columns of ``M`` that belong to it and drives its ``c_i`` rows.  This is
MATLAB's bookkeeping: e.g. a single ``[2, 3]`` block needs a 3×2 ``M``.

Upper bound
-----------
Fan, Tits & Doyle (1991) and Young, Newlin & Doyle (1995): if there are block-diagonal
scalings :math:`D_L, D_R` commuting with the structure (``d_i I`` on a full block, any
invertible :math:`T_i` on a repeated scalar block, the same on both sides) and a Hermitian
:math:`\tilde G` that is non-zero only on the real blocks such that, with
:math:`M_D = D_L M D_R^{-1}`,

.. math::

    M_D^H M_D + j(\tilde G M_D - M_D^H \tilde G^H) \preceq \beta^2 I ,

then :math:`\mu(M) \le \beta`.  Multiplying by :math:`D_R^H (\cdot) D_R` gives the LMI form
used by SLICOT AB13MD and MATLAB's ``VLmi``

.. math::

    M^H X_L M + j(G M - M^H G^H) - \beta^2 X_R \preceq 0, \qquad
    X_L = D_L^H D_L,\; X_R = D_R^H D_R,\; G = D_R^H \tilde G D_L,

which is what :class:`MuResult` returns (``d_left``, ``d_right``, ``g``) and what
:func:`lmi_residual` checks.  For a purely complex structure :math:`G = 0` and the bound is
:math:`\bar\sigma(D_L M D_R^{-1})` (Packard & Doyle 1993, section 8).  The scalings are found
by minimising :math:`\lambda_{\max}` of the left-hand side over
:math:`(\log d, T, \tilde G)`, starting from Osborne balancing of the block-norm matrix,
with a quasi-Newton (BFGS) method applied to the log-sum-exp smoothing
:math:`t\log\sum_k e^{\lambda_k/t}` of the eigenvalues with continuation
:math:`t\to 0` (an LMI-free method).  *Any* scaling yields a valid bound; the optimiser only
decides how tight it is, and the exact :math:`\lambda_{\max}` at the best scaling seen is
returned.  That descent is not convex in (log d, G) and can stall on badly scaled mixed
problems; when real blocks are present and the bounds have not met, the upper bound is then
refined by the method of centers for its generalized eigenvalue problem (Boyd & El Ghaoui
1993), which is quasi-convex in (X, G) and reaches the LMI optimum (:func:`_gevp_centers`).

Lower bound
-----------
Packard & Doyle (1993, section 9) power iteration: with :math:`Q` structured and
:math:`\bar\sigma(Q) \le 1`, every eigenvalue :math:`\lambda` of :math:`QM` gives
:math:`\det(I - M Q/\lambda) = 0`, so :math:`\mu \ge |\lambda|`.  The iteration alternates
:math:`a = Mb/\lVert Mb\rVert`, :math:`\ell = M^H y/\lVert M^H y\rVert` and aligns
:math:`b = Qa`, :math:`y = Q^H\ell` block by block (full block: :math:`b_i \parallel \ell_i`,
:math:`\lVert b_i\rVert = \lVert a_i\rVert`; complex scalar: :math:`b_i = q_i a_i`,
:math:`q_i = \overline{\ell_i^H a_i}/|\ell_i^H a_i|`; real scalar: :math:`q_i = \pm 1`).
It is started from the singular vectors of the optimally scaled matrix and from seeded random
vectors.  With real blocks, a certificate needs a *real* eigenvalue; following the real
direction idea of Young & Doyle (1990, 1997), real directions :math:`q` found by the
iteration (and, for few real blocks, the vertices of :math:`[-1,1]^{n_r}`) are polished by a
gain search along the ray :math:`\delta_r = \alpha q`: the real loop is closed
(:math:`M_c(\alpha)` is the LFT seen by the complex blocks) and the smallest
:math:`\alpha` with :math:`\alpha\,\mu_{lb}(M_c(\alpha)) \ge 1` is bracketed and bisected.
Every candidate is verified: :math:`\sigma_{\min}(I - M\Delta)` must be at round-off
level, or the candidate is discarded.

For purely real structures μ is discontinuous in M and the lower bound can honestly be 0
(e.g. a complex 1×1 ``M`` with a real scalar block has μ = 0 exactly, and the upper bound
then also reaches 0).

Implementation notes
--------------------
The inner loops (smoothed eigenvalue objective and its gradient, BFGS, power iteration) are
numba kernels compiled with ``cache=True``: the first call in a fresh checkout spends a
one-time JIT compilation (15–40 s on a 2-core machine, more under load); later processes load
the cache from ``ssamb/__pycache__``.  The engine works on a square, zero-padded copy of ``M``
(a non-square ``[r, c]`` block becomes ``max(r, c)`` square, which leaves μ and both bounds
unchanged) and maps scalings and Δ back to the user's shapes.  BLAS runs single-threaded
(:mod:`ssamb._threads`): for these small matrices threads only cost time.

References
----------
* A. Packard, J. Doyle, "The complex structured singular value", Automatica 29(1), 1993.
* M. Fan, A. Tits, J. Doyle, "Robustness in the presence of mixed parametric uncertainty and
  unmodeled dynamics", IEEE TAC 36(1), 1991.
* P. Young, M. Newlin, J. Doyle, "Computing bounds for the mixed μ problem", Int. J. Robust
  Nonlinear Control 5, 1995.
* P. Young, J. Doyle, "A lower bound for the mixed μ problem", IEEE TAC 42(1), 1997.
* S. Boyd, L. El Ghaoui, "Method of centers for minimizing generalized eigenvalues", Linear
  Algebra Appl. 188-189, 1993.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numba as nb
import numpy as np

__all__ = [
    "Block",
    "MuResult",
    "parse_blk",
    "mussv",
    "lmi_residual",
    "perturbation_residual",
    "structured_norm",
]

# internal block kinds
_REAL, _CSCALAR, _FULL = 0, 1, 2
_KIND_NAMES = {_REAL: "real scalar", _CSCALAR: "complex scalar", _FULL: "full complex"}


# ----------------------------------------------------------------------------------------
# block structure
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Block:
    """One uncertainty block.

    Attributes
    ----------
    kind : int
        0 real repeated scalar, 1 complex repeated scalar, 2 full complex block.
    r, c : int
        :math:`\\Delta_i` is ``r × c`` (``c == r`` for scalar blocks); the block reads ``r``
        columns of ``M`` and drives ``c`` rows of ``M``.
    """

    kind: int
    r: int
    c: int

    @property
    def n(self) -> int:
        """Size of the square (zero-padded) internal block, ``max(r, c)``."""
        return max(self.r, self.c)


def parse_blk(blk) -> tuple[Block, ...]:
    """Parse a MATLAB-style block structure (see the module docstring).

    Raises
    ------
    ValueError
        If a row is not of one of the forms ``[-r, 0]``, ``[r, 0]``, ``[r, c>0]``.
    """
    arr = np.asarray(blk)
    if arr.ndim == 1 and arr.size == 2:
        arr = arr.reshape(1, 2)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] == 0:
        raise ValueError(f"blk must be a non-empty list of [r, c] rows, got shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)):
        raise ValueError("blk must contain finite integers")
    if np.any(arr != np.round(arr)):
        raise ValueError("blk must contain integers")
    out = []
    for i, (r, c) in enumerate(arr.astype(int)):
        if c == 0 and r < 0:
            out.append(Block(_REAL, -r, -r))
        elif c == 0 and r > 0:
            out.append(Block(_CSCALAR, r, r))
        elif c > 0 and r > 0:
            out.append(Block(_FULL, r, c))
        else:
            raise ValueError(
                f"blk row {i} = [{r}, {c}] is invalid: use [-r, 0] (repeated real scalar), "
                "[r, 0] (repeated complex scalar) or [r, c] with r, c > 0 (full block)"
            )
    return tuple(out)


def _blocks_to_array(blocks) -> np.ndarray:
    rows = []
    for b in blocks:
        if b.kind == _REAL:
            rows.append([-b.r, 0])
        elif b.kind == _CSCALAR:
            rows.append([b.r, 0])
        else:
            rows.append([b.r, b.c])
    return np.array(rows, dtype=int)


@dataclass(frozen=True)
class _Layout:
    """Index bookkeeping between the user's M (p×q) and the internal padded square M (n×n)."""

    blocks: tuple
    p: int
    q: int
    n: int
    kinds: np.ndarray  # (nblk,)
    offs: np.ndarray  # internal offsets
    sizes: np.ndarray  # internal (square) sizes
    row_idx: tuple  # per block: indices of M rows (length c)
    col_idx: tuple  # per block: indices of M columns (length r)
    int_rows: np.ndarray  # internal row index of each M row (length p)
    int_cols: np.ndarray  # internal column index of each M column (length q)
    square: bool  # no padding: the internal matrix is M itself


def _layout(blocks) -> _Layout:
    kinds, offs, sizes, row_idx, col_idx, int_rows, int_cols = [], [], [], [], [], [], []
    o = pr = qc = 0
    for b in blocks:
        kinds.append(b.kind)
        offs.append(o)
        sizes.append(b.n)
        row_idx.append(np.arange(pr, pr + b.c))
        col_idx.append(np.arange(qc, qc + b.r))
        int_rows.extend(range(o, o + b.c))
        int_cols.extend(range(o, o + b.r))
        o += b.n
        pr += b.c
        qc += b.r
    return _Layout(
        blocks=tuple(blocks), p=pr, q=qc, n=o,
        kinds=np.array(kinds, dtype=np.int64), offs=np.array(offs, dtype=np.int64),
        sizes=np.array(sizes, dtype=np.int64), row_idx=tuple(row_idx), col_idx=tuple(col_idx),
        int_rows=np.array(int_rows, dtype=np.int64), int_cols=np.array(int_cols, dtype=np.int64),
        square=all(b.r == b.c for b in blocks),
    )


def _check_matrix(M, lay: _Layout) -> np.ndarray:
    M = np.asarray(M)
    if M.ndim == 0:
        M = M.reshape(1, 1)
    if M.ndim != 2:
        raise ValueError(f"M must be a 2-D matrix, got {M.ndim} dimensions")
    if not np.issubdtype(M.dtype, np.number):
        raise ValueError("M must be numeric")
    M = np.ascontiguousarray(M, dtype=np.complex128)
    if not np.isfinite(M).all():
        raise ValueError("M contains NaN or inf")
    if M.shape != (lay.p, lay.q):
        raise ValueError(
            f"M has shape {M.shape} but blk requires (sum of c, sum of r) = ({lay.p}, {lay.q}): "
            "a block [r, c] reads r columns and drives c rows of M (MATLAB mussv convention)"
        )
    return M


def _embed(M: np.ndarray, lay: _Layout) -> np.ndarray:
    if lay.square:
        return M
    Mi = np.zeros((lay.n, lay.n), dtype=np.complex128)
    Mi[np.ix_(lay.int_rows, lay.int_cols)] = M
    return Mi


def structured_norm(delta: np.ndarray, blk) -> float:
    """:math:`\\bar\\sigma(\\Delta) = \\max_i \\bar\\sigma(\\Delta_i)` of a block-diagonal
    ``delta`` (``(sum r) × (sum c)``); raises ``ValueError`` if ``delta`` is not in the
    structure (off-diagonal blocks, non-real real blocks, non-scalar scalar blocks)."""
    blocks = parse_blk(blk)
    lay = _layout(blocks)
    delta = np.asarray(delta, dtype=np.complex128)
    if delta.shape != (lay.q, lay.p):
        raise ValueError(f"delta must be {(lay.q, lay.p)}, got {delta.shape}")
    mask = np.zeros(delta.shape, dtype=bool)
    s = 0.0
    scale = max(1.0, float(np.max(np.abs(delta)))) if delta.size else 1.0
    tol = 1e-10 * scale
    for b, ri, ci in zip(blocks, lay.col_idx, lay.row_idx):
        sub = delta[np.ix_(ri, ci)]
        mask[np.ix_(ri, ci)] = True
        if b.kind != _FULL:
            d0 = sub[0, 0]
            if np.max(np.abs(sub - d0 * np.eye(b.r))) > tol:
                raise ValueError("scalar block of delta is not a multiple of the identity")
            if b.kind == _REAL and abs(d0.imag) > tol:
                raise ValueError("real block of delta is not real")
        s = max(s, float(np.linalg.norm(sub, 2)) if sub.size else 0.0)
    if np.any(np.abs(delta[~mask]) > tol):
        raise ValueError("delta is not block diagonal with the structure blk")
    return s


# ----------------------------------------------------------------------------------------
# numba kernels (internal square representation)
# ----------------------------------------------------------------------------------------
@nb.njit(cache=True)
def _mm(A, B):
    n, m = A.shape
    p = B.shape[1]
    C = np.zeros((n, p), dtype=np.complex128)
    for i in range(n):
        for k in range(m):
            a = A[i, k]
            if a != 0:
                for j in range(p):
                    C[i, j] += a * B[k, j]
    return C


@nb.njit(cache=True)
def _ct(A):
    n, m = A.shape
    B = np.empty((m, n), dtype=np.complex128)
    for i in range(n):
        for j in range(m):
            B[j, i] = np.conj(A[i, j])
    return B


def _osborne(M, lay, nsweep=10):
    """Osborne-type balancing of the block Frobenius-norm matrix B (B_ij = ||M_ij||_F):
    log-scalings s_i (one per block) that (nearly) minimise ||diag(e^s) B diag(e^-s)||_F.
    Simultaneous (Jacobi) form of Osborne's update s_i += log(c_i / r_i) / 4, damped."""
    A2 = (M.real ** 2 + M.imag ** 2)
    B2 = np.add.reduceat(np.add.reduceat(A2, lay.offs, axis=0), lay.offs, axis=1)
    np.fill_diagonal(B2, 0.0)
    floor = 1e-30 * float(B2.sum()) + 1e-300
    s = np.zeros(B2.shape[0])
    if B2.shape[0] == 1:
        return s
    for _ in range(nsweep):
        BE = B2 * np.exp(2.0 * (s[:, None] - s[None, :]))
        step = 0.125 * np.log((BE.sum(axis=0) + floor) / (BE.sum(axis=1) + floor))
        s = np.clip(s + step, -30.0, 30.0)
        if np.abs(step).max() < 1e-2:
            break
    return s - s.mean()


@nb.njit(cache=True)
def _build_T(x, offs, sizes, tpos, tfull, n):
    """Block-diagonal T and T^{-1} from the parameter vector.

    A diagonal-type block is e^{x} I.  A repeated-scalar block of size r > 1 is upper
    triangular with diagonal e^{theta_i} and complex strictly-upper entries (a Cholesky factor
    of X_i = T_i^H T_i, so every positive definite X_i is reachable); its inverse is by back
    substitution."""
    T = np.zeros((n, n), dtype=np.complex128)
    Ti = np.zeros((n, n), dtype=np.complex128)
    for k in range(offs.shape[0]):
        o = offs[k]
        r = sizes[k]
        p0 = tpos[k]
        if tfull[k] == 0:
            d = np.exp(x[p0])
            for i in range(r):
                T[o + i, o + i] = d
                Ti[o + i, o + i] = 1.0 / d
        else:
            for i in range(r):
                T[o + i, o + i] = np.exp(x[p0 + i])
            idx = p0 + r
            for i in range(r):
                for j in range(i + 1, r):
                    T[o + i, o + j] = x[idx] + 1j * x[idx + 1]
                    idx += 2
            for j in range(r):
                Ti[o + j, o + j] = 1.0 / T[o + j, o + j]
                for i in range(j - 1, -1, -1):
                    acc = 0.0 + 0.0j
                    for m in range(i + 1, j + 1):
                        acc += T[o + i, o + m] * Ti[o + m, o + j]
                    Ti[o + i, o + j] = -acc / T[o + i, o + i]
    return T, Ti


@nb.njit(cache=True)
def _build_G(x, offs, sizes, kinds, gpos, n):
    G = np.zeros((n, n), dtype=np.complex128)
    for k in range(offs.shape[0]):
        if kinds[k] != 0:
            continue
        o = offs[k]
        r = sizes[k]
        g0 = gpos[k]
        for i in range(r):
            G[o + i, o + i] = x[g0 + i]
        idx = g0 + r
        for i in range(r):
            for j in range(i + 1, r):
                v = x[idx] + 1j * x[idx + 1]
                G[o + i, o + j] = v
                G[o + j, o + i] = np.conj(v)
                idx += 2
    return G


@nb.njit(cache=True)
def _eval(x, M, kinds, offs, sizes, tpos, tfull, gpos, has_real, t, grad):
    """Smoothed objective f_t = t log sum exp(lambda_k / t) of the eigenvalues of
    H = M_T^H M_T + j(Gt M_T - M_T^H Gt), Gt = T^{-H} G T^{-1}, its gradient with respect to
    x = (log-scalings / triangular T entries, G entries) written into grad, and lambda_max.

    G (the unscaled LMI variable) rather than Gt is the parameter: the LMI is affine in G,
    which keeps the problem well scaled when the D-scalings spread over decades."""
    n = M.shape[0]
    T, Ti = _build_T(x, offs, sizes, tpos, tfull, n)
    MT = _mm(_mm(T, M), Ti)
    MTH = _ct(MT)
    H = _mm(MTH, MT)
    G = np.zeros((n, n), dtype=np.complex128)
    if has_real:
        G = _mm(_mm(_ct(Ti), _build_G(x, offs, sizes, kinds, gpos, n)), Ti)
        GM = _mm(G, MT)
        for i in range(n):
            for j in range(n):
                H[i, j] += 1j * (GM[i, j] - np.conj(GM[j, i]))
    for i in range(n):
        for j in range(i, n):
            hij = 0.5 * (H[i, j] + np.conj(H[j, i]))
            if not (np.isfinite(hij.real) and np.isfinite(hij.imag)):
                return np.inf, np.inf
            H[i, j] = hij
            H[j, i] = np.conj(hij)
    w, V = np.linalg.eigh(H)
    lam = w[n - 1]
    wts = np.zeros(n)
    if t > 0.0:
        ssum = 0.0
        for i in range(n):
            wts[i] = np.exp((w[i] - lam) / t)
            ssum += wts[i]
        f = lam + t * np.log(ssum)
        for i in range(n):
            wts[i] /= ssum
    else:
        f = lam
        wts[n - 1] = 1.0
    # W = sum_k wts_k v_k v_k^H
    W = np.zeros((n, n), dtype=np.complex128)
    for kk in range(n):
        if wts[kk] > 1e-16:
            for i in range(n):
                vi = wts[kk] * V[i, kk]
                for j in range(n):
                    W[i, j] += vi * np.conj(V[j, kk])
    if has_real:
        for i in range(n):
            for j in range(n):
                MTH[i, j] += 1j * G[i, j]
    K = _mm(W, MTH)
    R = _mm(MT, K)
    KM = _mm(K, MT)
    for i in range(n):
        for j in range(n):
            R[i, j] -= KM[i, j]
    if has_real:
        for i in range(n):
            for j in range(n):
                MTH[i, j] -= 1j * G[i, j]
    for i in range(grad.shape[0]):
        grad[i] = 0.0
    for k in range(offs.shape[0]):
        o = offs[k]
        r = sizes[k]
        if has_real and kinds[k] == 0:
            # P = j (M_T W - W M_T^H) on the block: df = tr(P dGt); with Gt = Ti^H G Ti,
            # dGt = Ti^H dG Ti - E^H Gt - Gt E (E = dT T^{-1}), hence
            # df/dG = Ti P Ti^H and R_kk -> R_kk - P Gt_kk in the T gradient.
            P = np.zeros((r, r), dtype=np.complex128)
            for i in range(r):
                for j in range(r):
                    acc2 = 0.0 + 0.0j
                    for m in range(n):
                        acc2 += MT[o + i, m] * W[m, o + j] - W[o + i, m] * MTH[m, o + j]
                    P[i, j] = 1j * acc2
            for i in range(r):
                for j in range(r):
                    acc2 = 0.0 + 0.0j
                    for m in range(r):
                        acc2 += P[i, m] * G[o + m, o + j]
                    R[o + i, o + j] -= acc2
            Tik = np.zeros((r, r), dtype=np.complex128)
            for i in range(r):
                for j in range(r):
                    Tik[i, j] = Ti[o + i, o + j]
            PG = _mm(_mm(Tik, P), _ct(Tik))
            g0 = gpos[k]
            for i in range(r):
                grad[g0 + i] = PG[i, i].real
            idx = g0 + r
            for i in range(r):
                for j in range(i + 1, r):
                    grad[idx] = 2.0 * PG[i, j].real
                    grad[idx + 1] = 2.0 * PG[i, j].imag
                    idx += 2
        if tfull[k] == 0:
            acc = 0.0
            for i in range(r):
                acc += R[o + i, o + i].real
            grad[tpos[k]] = 2.0 * acc
        else:
            # S = Ti_k R_kk ; df = 2 Re sum S_ji dT_ij ; T_ii = exp(theta_i)
            p0 = tpos[k]
            idx = p0 + r
            for i in range(r):
                for j in range(i, r):
                    sji = 0.0 + 0.0j
                    for m in range(r):
                        sji += Ti[o + j, o + m] * R[o + m, o + i]
                    if j == i:
                        grad[p0 + i] = 2.0 * (sji * T[o + i, o + i]).real
                    else:
                        grad[idx] = 2.0 * sji.real
                        grad[idx + 1] = -2.0 * sji.imag
                        idx += 2
    return f, lam


@nb.njit(cache=True)
def _upper_opt(M, kinds, offs, sizes, tpos, tfull, gpos, has_real, x0, taus, maxit, max_evals):
    """Continuation (t -> 0) BFGS on the smoothed lambda_max; returns the best x seen
    (by the exact lambda_max), that lambda_max and the number of evaluations."""
    npar = x0.shape[0]
    g = np.zeros(npar)
    gn = np.zeros(npar)
    x = x0.copy()
    f, lam = _eval(x, M, kinds, offs, sizes, tpos, tfull, gpos, has_real, 0.0, g)
    best_lam = lam
    best_x = x.copy()
    nev = 1
    if not (lam > 0.0):
        return best_x, best_lam, nev
    for st in range(taus.shape[0]):
        t = taus[st] * max(best_lam, 1e-300)
        f, lam = _eval(x, M, kinds, offs, sizes, tpos, tfull, gpos, has_real, t, g)
        nev += 1
        Hi = np.eye(npar)
        first = True
        for it in range(maxit):
            p = np.zeros(npar)
            for i in range(npar):
                acc = 0.0
                for j in range(npar):
                    acc += Hi[i, j] * g[j]
                p[i] = -acc
            gp = 0.0
            for i in range(npar):
                gp += g[i] * p[i]
            if not (gp < 0.0):
                gp = 0.0
                for i in range(npar):
                    for j in range(npar):
                        Hi[i, j] = 1.0 if i == j else 0.0
                    p[i] = -g[i]
                    gp -= g[i] * g[i]
                if gp == 0.0:
                    break
            # cap the step (log-scalings: a factor e^3 at most per step)
            pmax = 0.0
            for i in range(npar):
                pmax = max(pmax, abs(p[i]))
            step = 1.0
            if pmax * step > 3.0:
                step = 3.0 / pmax
            accepted = False
            for ls in range(40):
                xn = np.empty(npar)
                for i in range(npar):
                    xn[i] = x[i] + step * p[i]
                fn, lamn = _eval(xn, M, kinds, offs, sizes, tpos, tfull, gpos, has_real, t, gn)
                nev += 1
                if lamn < best_lam:
                    best_lam = lamn
                    for i in range(npar):
                        best_x[i] = xn[i]
                if fn <= f + 1e-4 * step * gp:
                    accepted = True
                    break
                step *= 0.3
            if not accepted:
                break
            s = np.empty(npar)
            y = np.empty(npar)
            for i in range(npar):
                s[i] = xn[i] - x[i]
                y[i] = gn[i] - g[i]
            sy = 0.0
            yy = 0.0
            ss = 0.0
            for i in range(npar):
                sy += s[i] * y[i]
                yy += y[i] * y[i]
                ss += s[i] * s[i]
            if sy > 1e-14 * np.sqrt(ss * yy):
                if first:
                    for i in range(npar):
                        for j in range(npar):
                            Hi[i, j] = sy / yy if i == j else 0.0
                    first = False
                rho = 1.0 / sy
                Hy = np.zeros(npar)
                for i in range(npar):
                    acc = 0.0
                    for j in range(npar):
                        acc += Hi[i, j] * y[j]
                    Hy[i] = acc
                yHy = 0.0
                for i in range(npar):
                    yHy += y[i] * Hy[i]
                for i in range(npar):
                    for j in range(npar):
                        Hi[i, j] += (-rho * (s[i] * Hy[j] + Hy[i] * s[j])
                                     + (rho * rho * yHy + rho) * s[i] * s[j])
            df = f - fn
            x = xn
            f = fn
            for i in range(npar):
                g[i] = gn[i]
            if best_lam <= 0.0 or nev >= max_evals:
                break
            gnorm = 0.0
            for i in range(npar):
                gnorm = max(gnorm, abs(g[i]))
            if df <= 1e-4 * t and gnorm <= 1e-5 * max(best_lam, 1e-300):
                break
            if df <= 1e-9 * abs(f) and it > 2:
                break
        if best_lam <= 0.0 or nev >= max_evals:
            break
        for i in range(npar):
            x[i] = best_x[i]
    return best_x, best_lam, nev


@nb.njit(cache=True)
def _norm(v):
    acc = 0.0
    for i in range(v.shape[0]):
        acc += v[i].real * v[i].real + v[i].imag * v[i].imag
    return np.sqrt(acc)


@nb.njit(cache=True)
def _matvec(M, v):
    n, m = M.shape
    out = np.zeros(n, dtype=np.complex128)
    for i in range(n):
        acc = 0.0 + 0.0j
        for j in range(m):
            acc += M[i, j] * v[j]
        out[i] = acc
    return out


@nb.njit(cache=True)
def _align(kinds, offs, sizes, a, l, forward):
    """Block alignment of the power iteration.

    forward=True returns b = Q a (from a and l); forward=False returns y = Q^H l."""
    n = a.shape[0]
    out = np.zeros(n, dtype=np.complex128)
    for k in range(offs.shape[0]):
        o = offs[k]
        r = sizes[k]
        if kinds[k] == 2:
            na = 0.0
            nl = 0.0
            for i in range(o, o + r):
                na += a[i].real * a[i].real + a[i].imag * a[i].imag
                nl += l[i].real * l[i].real + l[i].imag * l[i].imag
            # forward: b = (|a|/|l|) l (else a); backward: y = (|l|/|a|) a (else l)
            num, den = (np.sqrt(na), np.sqrt(nl)) if forward else (np.sqrt(nl), np.sqrt(na))
            src, alt = (l, a) if forward else (a, l)
            for i in range(o, o + r):
                out[i] = (num / den) * src[i] if den > 1e-300 else alt[i]
        else:
            c = 0.0 + 0.0j
            for i in range(o, o + r):
                c += np.conj(l[i]) * a[i]
            if kinds[k] == 1:
                ac = abs(c)
                ph = c / ac if ac > 1e-300 else 1.0 + 0.0j
                if forward:
                    q = np.conj(ph)
                    for i in range(o, o + r):
                        out[i] = q * a[i]
                else:
                    for i in range(o, o + r):
                        out[i] = ph * l[i]
            else:
                q = 1.0 if c.real >= 0.0 else -1.0
                if forward:
                    for i in range(o, o + r):
                        out[i] = q * a[i]
                else:
                    for i in range(o, o + r):
                        out[i] = q * l[i]
    return out


@nb.njit(cache=True)
def _scaled(v, f):
    out = np.empty(v.shape[0], dtype=np.complex128)
    for i in range(v.shape[0]):
        out[i] = v[i] * f
    return out


@nb.njit(cache=True)
def _power(M, kinds, offs, sizes, b0, l0, maxit, tol):
    """Packard-Doyle power iteration; returns (beta, a, b, l)."""
    MH = _ct(M)
    b = _scaled(b0, 1.0 / max(_norm(b0), 1e-300))
    l = _scaled(l0, 1.0 / max(_norm(l0), 1e-300))
    a = _matvec(M, b)
    beta = _norm(a)
    if beta == 0.0:
        return 0.0, a, b, l
    a = _scaled(a, 1.0 / beta)
    prev = -1.0
    for it in range(maxit):
        y = _align(kinds, offs, sizes, a, l, False)
        lt = _matvec(MH, y)
        bl = _norm(lt)
        if bl == 0.0:
            break
        l = _scaled(lt, 1.0 / bl)
        b = _align(kinds, offs, sizes, a, l, True)
        nbv = _norm(b)
        if nbv == 0.0:
            break
        b = _scaled(b, 1.0 / nbv)
        at = _matvec(M, b)
        beta = _norm(at)
        if beta == 0.0:
            break
        a = _scaled(at, 1.0 / beta)
        if it > 3 and abs(beta - prev) <= tol * beta and abs(bl - beta) <= 10 * tol * beta:
            break
        prev = beta
    return beta, a, b, l


def _power_c(M, kinds, offs, sizes, b0, l0, maxit, tol):
    """:func:`_power` with C-contiguous arguments (one compiled specialisation)."""
    c = np.ascontiguousarray
    return _power(c(M, dtype=np.complex128), kinds, offs, sizes, c(b0, dtype=np.complex128),
                  c(l0, dtype=np.complex128), maxit, tol)


def _build_Q(kinds, offs, sizes, a, l, n):
    """Structured Q aligning a to b = Q a (rank-one full blocks, unimodular scalars) and its
    norm σ̄(Q) = max_k ||Q_k|| (||b_k|| / ||a_k|| for a rank-one full block, 1 for scalars)."""
    b = _align(kinds, offs, sizes, a, l, True)
    Q = np.zeros((n, n), dtype=np.complex128)
    qn = 0.0
    for k, o, r in zip(kinds, offs, sizes):
        sl = slice(o, o + r)
        if k == _FULL:
            na2 = np.vdot(a[sl], a[sl]).real
            if na2 > 1e-300:
                Q[sl, sl] = np.outer(b[sl], a[sl].conj()) / na2
                qn = max(qn, float(np.sqrt(np.vdot(b[sl], b[sl]).real / na2)))
        else:
            cc = np.vdot(l[sl], a[sl])
            if k == _CSCALAR:
                q = np.conj(cc) / abs(cc) if abs(cc) > 1e-300 else 1.0
            else:
                q = 1.0 if cc.real >= 0.0 else -1.0
            Q[sl, sl] = q * np.eye(r)
            qn = max(qn, 1.0)
    return Q, qn


def _eigvals(A):
    return np.linalg.eigvals(A)


# ----------------------------------------------------------------------------------------
# result
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MuResult:
    """Bounds on μ with their certificates.

    Attributes
    ----------
    upper, lower : float
        ``lower <= mu <= upper``.
    delta : ndarray or None
        ``(sum r) × (sum c)`` block-diagonal perturbation in the structure with
        ``det(I - M @ delta) ≈ 0`` and ``structured_norm(delta) = 1/lower``; ``None`` when
        ``lower == 0`` (no destabilising perturbation was found).
    d_left, d_right : ndarray
        Block-diagonal scalings (``p × p`` on the rows of M, ``q × q`` on its columns;
        ``d_i I`` on a full block, a full invertible ``T_i`` on a repeated scalar block).
        Defined up to a common positive factor.
    g : ndarray
        ``q × p`` G-scaling, non-zero only on real blocks (Hermitian there); zero for a purely
        complex structure.  Together: ``M^H X_L M + j(g M - M^H g^H) - upper^2 X_R <= 0`` with
        ``X_L = d_left^H d_left``, ``X_R = d_right^H d_right`` (see :func:`lmi_residual`).
    blk : ndarray
        The normalised ``(nblk, 2)`` block structure.
    det_residual : float
        :math:`\\sigma_{\\min}(I - M\\Delta) / (1 + \\sigma_{\\max}(I - M\\Delta))` of the
        returned ``delta`` (0 when ``delta`` is None); candidates above 1e-8 are rejected.
    lower_method : str
        Which procedure produced the lower bound.
    n_evals : int
        Eigenvalue evaluations spent on the upper bound.
    """

    upper: float
    lower: float
    delta: np.ndarray | None
    d_left: np.ndarray
    d_right: np.ndarray
    g: np.ndarray
    blk: np.ndarray
    det_residual: float = 0.0
    lower_method: str = ""
    n_evals: int = 0

    @property
    def bounds(self) -> tuple[float, float]:
        """``(upper, lower)``, MATLAB's ``bounds`` order."""
        return (self.upper, self.lower)


# ----------------------------------------------------------------------------------------
# helpers around the kernels
# ----------------------------------------------------------------------------------------
def _param_layout(lay: _Layout):
    tpos = np.zeros(len(lay.blocks), dtype=np.int64)
    tfull = np.zeros(len(lay.blocks), dtype=np.int64)
    gpos = -np.ones(len(lay.blocks), dtype=np.int64)
    k = 0
    for i, b in enumerate(lay.blocks):
        tpos[i] = k
        if b.kind != _FULL and b.n > 1:
            tfull[i] = 1
            k += b.n * b.n
        else:
            k += 1
    for i, b in enumerate(lay.blocks):
        if b.kind == _REAL:
            gpos[i] = k
            k += b.n * b.n
    return tpos, tfull, gpos, k


def _x_from_logd(s, lay, tpos, tfull, npar):
    x = np.zeros(npar)
    for i, b in enumerate(lay.blocks):
        if tfull[i]:
            x[tpos[i]:tpos[i] + b.n] = s[i]
        else:
            x[tpos[i]] = s[i]
    return x


def _det_residual(M: np.ndarray, delta: np.ndarray) -> float:
    MD = M @ delta
    A = np.eye(M.shape[0]) - MD
    sv = np.linalg.svd(A, compute_uv=False)
    return float(sv[-1] / (1.0 + sv[0]))


def perturbation_residual(M, delta) -> float:
    """Relative singularity of ``I - M @ delta``: ``σ_min(I - MΔ) / (1 + σ_max(I - MΔ))``
    (0 for an exactly singular matrix)."""
    return _det_residual(np.asarray(M, dtype=np.complex128), np.asarray(delta, dtype=np.complex128))


def lmi_residual(M, result: MuResult) -> float:
    """Normalised largest eigenvalue of the upper-bound certificate, in its scaled form

    .. math:: M_D^H M_D + j(\\tilde G M_D - M_D^H \\tilde G^H) - \\beta^2 I, \\quad
              M_D = D_L M D_R^{-1},\\; \\tilde G = D_R^{-H} G D_L^{-1},\\; \\beta = \\text{upper},

    divided by :math:`\\max(\\beta^2, \\bar\\sigma(M_D)^2)`.  It is congruent to the LMI
    :math:`M^H X_L M + j(G M - M^H G^H) - \\beta^2 X_R` (multiply by :math:`D_R^H \\cdot D_R`),
    so a value ``<= ~1e-9`` certifies ``mu(M) <= upper``; the scaled form is the numerically
    meaningful one when the scalings span many decades.
    """
    M = np.asarray(M, dtype=np.complex128)
    if M.ndim == 0:
        M = M.reshape(1, 1)
    DL, DR = result.d_left, result.d_right
    MD = DL @ np.linalg.solve(DR.T, M.T).T  # D_L M D_R^{-1}
    Gt = np.linalg.solve(DR.conj().T, np.linalg.solve(DL.T, result.g.T).T)  # D_R^-H G D_L^-1
    H = MD.conj().T @ MD
    GM = Gt @ MD
    L = H + 1j * (GM - GM.conj().T) - result.upper ** 2 * np.eye(H.shape[0])
    L = 0.5 * (L + L.conj().T)
    lam = float(np.linalg.eigvalsh(L)[-1])
    den = max(result.upper ** 2, float(np.linalg.norm(H, 2)), 1e-300)
    return lam / den


def _to_user_delta(Dint: np.ndarray, lay: _Layout) -> np.ndarray:
    """Internal n×n block-diagonal Δ -> user's q×p Δ (rows: M columns, cols: M rows)."""
    if lay.square:
        return Dint
    return Dint[np.ix_(lay.int_cols, lay.int_rows)]


def _verify_candidate(M, lay, Dint):
    """Return (lower, delta_user, residual) or None if the candidate does not certify.

    Full blocks of the candidates are rank one, so their Frobenius norm is their 2-norm (in
    general it is an upper bound of it, which keeps the lower bound valid)."""
    delta = _to_user_delta(Dint, lay)
    nrm = 0.0
    for b, o, sz in zip(lay.blocks, lay.offs, lay.sizes):
        sub = Dint[o:o + sz, o:o + sz]
        if b.kind == _FULL:
            nrm = max(nrm, float(np.linalg.norm(sub)))  # Frobenius
        else:
            nrm = max(nrm, float(abs(sub[0, 0])))
    if not np.isfinite(nrm) or nrm <= 0.0:
        return None
    res = _det_residual(M, delta)
    if not res <= 1e-8:
        return None
    return 1.0 / nrm, delta, res


class _LowerSearch:
    """Collects lower-bound candidates Δ (internal coordinates) with a cheap estimate of
    1/σ̄(Δ); :meth:`finish` verifies them best-first and keeps the first that certifies."""

    def __init__(self, M, lay):
        self.M = M
        self.lay = lay
        self.cands = []
        self.best_est = 0.0

    def offer(self, Dint, est, method):
        if np.isfinite(est) and est > 0.0:
            self.cands.append((float(est), Dint, method))
            self.best_est = max(self.best_est, float(est))

    def finish(self):
        for est, Dint, method in sorted(self.cands, key=lambda c: -c[0]):
            out = _verify_candidate(self.M, self.lay, Dint)
            if out is not None:
                return out[0], out[1], out[2], method
        return 0.0, None, 0.0, "none found"


def _eig_candidates(QM, real_only: bool):
    lam = _eigvals(QM)
    if real_only:
        scale = max(1.0, float(np.abs(lam).max())) if lam.size else 1.0
        lam = lam[np.abs(lam.imag) <= 1e-11 * scale].real.astype(np.complex128)
    lam = lam[np.abs(lam) > 0]
    return lam[np.argsort(-np.abs(lam))]


def _offer_Q(search: _LowerSearch, Q, qn, Mi, has_real, method):
    """Offer Δ = Q/λ for the dominant (real, if needed) eigenvalue of QM; returns the
    estimate |λ|/σ̄(Q)."""
    lams = _eig_candidates(Q @ Mi, has_real)
    if lams.size == 0 or qn <= 0.0:
        return 0.0
    lam = complex(lams[0].real, 0.0) if has_real else lams[0]
    est = abs(lam) / qn
    search.offer(Q / lam, est, method)
    return est


def _complex_lower(Mc, kinds, offs, sizes, starts, maxit=200, tol=1e-10):
    """Complex-structure lower bound of a (small) matrix: power iteration + eigen check.

    Returns (lb, internal delta = Q/λ or None)."""
    n = Mc.shape[0]
    best = (0.0, None)
    for b0, l0 in starts:
        beta, a, b, l = _power_c(Mc, kinds, offs, sizes, b0, l0, maxit, tol)
        if beta == 0.0:
            continue
        Q, qn = _build_Q(kinds, offs, sizes, a, l, n)
        lams = _eig_candidates(Q @ Mc, False)
        if lams.size and qn > 0 and abs(lams[0]) / qn > best[0]:
            best = (float(abs(lams[0]) / qn), Q / lams[0])
    return best


# ----------------------------------------------------------------------------------------
# main entry point
# ----------------------------------------------------------------------------------------
def mussv(
    M,
    blk,
    *,
    seed: int = 0,
    n_restarts: int = 4,
    upper_tol: float = 1e-6,
    max_evals: int = 600,
    vertex_limit: int = 8,
) -> MuResult:
    """Upper and lower bounds of the structured singular value μ(M).

    Parameters
    ----------
    M : array_like, shape (sum c, sum r)
        Complex (or real) matrix; a scalar is taken as 1×1.
    blk : array_like of [r, c] rows
        MATLAB ``mussv`` block structure (module docstring): ``[-r, 0]`` repeated real
        scalar, ``[r, 0]`` repeated complex scalar, ``[r, c]`` full ``r × c`` complex block.
        ``M`` must be ``(sum c) × (sum r)``.
    seed : int
        Seed of the random restarts of the lower bound (results are deterministic for a given
        input and seed).
    n_restarts : int
        Number of random power-iteration restarts in addition to the start taken from the
        upper-bound singular vectors.
    upper_tol : float
        Smallest relative smoothing parameter of the upper-bound continuation (the bound is
        optimal to roughly this relative accuracy; it is always a valid bound).
    max_evals : int
        Budget of eigen-decompositions for the upper bound.
    vertex_limit : int
        With at most this many real blocks (purely real structures), all vertices of the real
        box are tried as lower-bound directions (``min(vertex_limit, 3)`` for mixed
        structures, whose rays are more expensive).

    Returns
    -------
    MuResult
        ``upper``, ``lower``, the perturbation ``delta`` (``None`` when ``lower == 0``), the
        scalings ``d_left``, ``d_right``, ``g``.

    Raises
    ------
    ValueError
        If ``M`` contains NaN/inf, is not 2-D, or its shape does not match ``blk``; or if
        ``blk`` is malformed.

    Notes
    -----
    ``lower <= upper`` holds up to round-off: both are certified (``lmi_residual`` and
    ``perturbation_residual``), and when they meet to round-off the upper bound is lifted to
    the lower one.  For purely complex structures with ``2 S + F <= 3`` (S repeated scalars, F
    full blocks) the upper bound equals μ (Packard & Doyle 1993); otherwise the gap can be
    non-zero.  With real blocks μ can be discontinuous and the lower bound may be 0.

    Examples
    --------
    Two 1×1 complex blocks on a diagonal matrix: μ is its largest entry.

    >>> import numpy as np
    >>> from ssamb.mu import mussv
    >>> r = mussv(np.diag([0.5, 0.3]), [[1, 1], [1, 1]])
    >>> round(r.upper, 6), round(r.lower, 6)
    (0.5, 0.5)
    """
    blocks = parse_blk(blk)
    lay = _layout(blocks)
    M = _check_matrix(M, lay)
    if not isinstance(n_restarts, (int, np.integer)) or n_restarts < 0:
        raise ValueError("n_restarts must be a non-negative integer")
    blk_arr = _blocks_to_array(blocks)
    Mi = _embed(M, lay)
    n = lay.n
    kinds, offs, sizes = lay.kinds, lay.offs, lay.sizes
    has_real = bool((kinds == _REAL).any())
    all_real = bool((kinds == _REAL).all())
    smax = float(np.linalg.norm(Mi, 2)) if n else 0.0

    tpos, tfull, gpos, npar = _param_layout(lay)

    if smax == 0.0:
        return _assemble(M, lay, np.zeros(npar), tpos, tfull, gpos, 1.0, 0.0, None, 0.0,
                         "zero matrix", 0, blk_arr)

    # ---------------- upper bound ----------------
    c = 1.0 / smax
    Mn = Mi * c
    s0 = _osborne(Mn, lay)
    x_osb = _x_from_logd(s0, lay, tpos, tfull, npar)
    x_id = _x_from_logd(np.zeros(len(blocks)), lay, tpos, tfull, npar)
    gtmp = np.zeros(npar)
    _, lam_osb = _eval(x_osb, Mn, kinds, offs, sizes, tpos, tfull, gpos, has_real, 0.0, gtmp)
    _, lam_id = _eval(x_id, Mn, kinds, offs, sizes, tpos, tfull, gpos, has_real, 0.0, gtmp)
    x0 = x_osb if lam_osb <= lam_id else x_id
    taus = np.array([t for t in (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8) if t >= upper_tol * 0.999])
    if len(blocks) == 1 and not has_real:
        # one complex block: mu = sigma_max (full) or spectral radius (repeated scalar) --
        # no diagonal scaling to optimise for a full block
        taus = taus if tfull[0] else taus[:0]
    xb, lamb, nev = _upper_opt(Mn, kinds, offs, sizes, tpos, tfull, gpos, has_real, x0,
                               taus, 60, int(max_evals))
    upper = float(np.sqrt(max(lamb, 0.0))) / c

    # ---------------- lower bound ----------------
    search = _LowerSearch(M, lay)
    if upper > 0.0:
        _lower_bound(search, Mi, Mn, lay, xb, tpos, tfull, has_real, all_real,
                     upper, seed, n_restarts, vertex_limit)
    lower, delta, det_res, method = search.finish()
    if has_real and lamb > 0.0 and lower < upper * (1.0 - 1e-6):
        # the bounds have not met: solve the upper bound's GEVP convexly
        xb, lamb = _gevp_centers(Mn, lay, xb, lamb, x_osb, tpos, tfull, gpos)
        upper = float(np.sqrt(max(lamb, 0.0))) / c
    if lower > upper:
        # both are certified, so the excess is round-off (mu attained): keep lower <= upper
        upper = lower
    return _assemble(M, lay, xb, tpos, tfull, gpos, c, upper, delta, lower,
                     method, nev, blk_arr, det_res=det_res)



# ----------------------------------------------------------------------------------------
# mixed structures: convex (Dinkelbach) refinement of the upper bound
# ----------------------------------------------------------------------------------------
def _herm_basis(lay, which: str) -> list:
    """Orthogonal Hermitian basis of a block-diagonal scaling space (``n × n`` matrices).

    ``which='X'``: the D-scaling space (``x I`` on a full block or a 1×1 block, any Hermitian
    ``X_k`` on a repeated scalar block); ``'G'``: the G space (any Hermitian ``G_k`` on a real
    block)."""
    n = lay.n
    out = []
    for k, b in enumerate(lay.blocks):
        o, r = int(lay.offs[k]), int(lay.sizes[k])
        if which == "G" and b.kind != _REAL:
            continue
        if r == 1 or (which == "X" and b.kind == _FULL):
            E = np.zeros((n, n), dtype=np.complex128)
            E[o:o + r, o:o + r] = np.eye(r)
            out.append(E)
            continue
        for i in range(r):
            E = np.zeros((n, n), dtype=np.complex128)
            E[o + i, o + i] = 1.0
            out.append(E)
        for i in range(r):
            for j in range(i + 1, r):
                for v in (1.0, 1j):
                    E = np.zeros((n, n), dtype=np.complex128)
                    E[o + i, o + j] = v
                    E[o + j, o + i] = np.conj(v)
                    out.append(E)
    return out


def _x_from_scalings(X, G, lay, tpos, tfull, gpos, npar) -> np.ndarray:
    """Parameter vector of :func:`_eval` from a block-diagonal ``X = T^H T`` (``T`` upper
    triangular per block, positive diagonal) and the unscaled LMI variable ``G``."""
    x = np.zeros(npar)
    for k in range(len(lay.blocks)):
        o, r = int(lay.offs[k]), int(lay.sizes[k])
        Xk = X[o:o + r, o:o + r]
        Xk = 0.5 * (Xk + Xk.conj().T)
        if tfull[k] == 0:
            x[tpos[k]] = 0.5 * np.log(Xk[0, 0].real)
        else:
            Tk = np.linalg.cholesky(Xk).conj().T
            p0 = tpos[k]
            x[p0:p0 + r] = np.log(np.diag(Tk).real)
            idx = p0 + r
            for i in range(r):
                for j in range(i + 1, r):
                    x[idx], x[idx + 1] = Tk[i, j].real, Tk[i, j].imag
                    idx += 2
        if gpos[k] >= 0:
            Gk = G[o:o + r, o:o + r]
            g0 = gpos[k]
            x[g0:g0 + r] = np.diag(Gk).real
            idx = g0 + r
            for i in range(r):
                for j in range(i + 1, r):
                    x[idx], x[idx + 1] = Gk[i, j].real, Gk[i, j].imag
                    idx += 2
    return x


def _gevp_centers(Mn, lay, x, lam, x_ref, tpos, tfull, gpos, theta=0.2, max_outer=200,
                  rtol=1e-9):
    r"""Refine a mixed-μ upper bound by the method of centers for its generalized eigenvalue
    problem (Boyd & El Ghaoui 1993, "Method of centers for minimizing generalized
    eigenvalues", Linear Algebra Appl. 188)

    .. math:: \min \lambda \;\text{s.t.}\; \lambda X - A(X, G) \succ 0,\; X \succ 0,\quad
              A = M^H X M + j(GM - M^H G),\quad \operatorname{tr} X = n,

    which is quasi-convex in (X, G).  At level :math:`\lambda_k` the analytic center of
    :math:`\{\lambda_k X - A \succ 0,\, X \succ 0\}` (maximiser of
    :math:`\log\det(\lambda_k X - A) + \log\det X`) is found by damped Newton steps, whose
    affine invariance makes them indifferent to how the variables are scaled; the
    generalized eigenvalue :math:`\lambda_c` at the center is a certified bound and the next
    level is :math:`\lambda_{k+1} = (1-\theta)\lambda_c + \theta\lambda_k`.  The problem is
    posed in the fixed coordinates of ``x_ref`` (Osborne balancing: a congruence, which keeps
    every sign), started from ``x``.  The fast (log d, G) descent of :func:`_upper_opt` is not
    convex in its variables and can stall on badly scaled mixed problems; this step reaches
    the LMI optimum (the one SLICOT AB13MD computes).  A center whose eigenvalue is not
    resolved above round-off is not used."""
    n = lay.n
    kinds, offs, sizes = lay.kinds, lay.offs, lay.sizes
    EX, EG = _herm_basis(lay, "X"), _herm_basis(lay, "G")
    eye = np.eye(n, dtype=np.complex128)
    FX = [E - (np.trace(E).real / n) * eye for E in EX[1:]]  # trace-free directions
    nx, ng = len(FX), len(EG)
    Gb = np.array(EG).reshape(-1, n, n)
    gtmp = np.zeros(x.shape[0])
    T0, T0i = _build_T(x_ref, offs, sizes, tpos, tfull, n)
    MT = T0 @ Mn @ T0i
    MH = MT.conj().T
    s = max(float(np.linalg.norm(MH @ MT, 2)), 1e-300)
    # start (X, G) of x in these coordinates, trace normalised
    T, _ = _build_T(x, offs, sizes, tpos, tfull, n)
    X0 = T0i.conj().T @ (T.conj().T @ T) @ T0i
    G0 = T0i.conj().T @ _build_G(x, offs, sizes, kinds, gpos, n) @ T0i
    f0 = n / np.trace(X0).real
    X0, G0 = X0 * f0, G0 * f0
    A0 = (MH @ X0 @ MT + 1j * (G0 @ MT - MH @ G0)) / s
    AXp = np.array([MH @ F @ MT / s for F in FX]).reshape(-1, n, n)
    AGp = np.array([1j * (E @ MT - MH @ E) / s for E in EG]).reshape(-1, n, n)
    F2p = np.array(FX + [np.zeros((n, n), np.complex128)] * ng).reshape(-1, n, n)
    P = nx + ng
    best_x, best_lam = x.copy(), float(lam)
    lev = best_lam * (1.0 + 1e-2)
    y = np.zeros(P)
    for _ in range(max_outer):
        lv = lev / s
        F10 = lv * X0 - A0
        F1p = np.concatenate([lv * F2p[:nx] - AXp, -AGp]).reshape(-1, n, n)

        def barrier(y):
            F1 = F10 + np.tensordot(y, F1p, axes=1)
            F2 = X0 + np.tensordot(y, F2p, axes=1)
            try:
                C1 = np.linalg.cholesky(0.5 * (F1 + F1.conj().T))
                C2 = np.linalg.cholesky(0.5 * (F2 + F2.conj().T))
            except np.linalg.LinAlgError:
                return np.inf, None, None
            return -2.0 * (np.log(np.diag(C1).real).sum() + np.log(np.diag(C2).real).sum()), C1, C2

        phi, C1, C2 = barrier(y)
        if not np.isfinite(phi):
            break
        for _newton in range(50):
            # S_p = C^{-1} F_p C^{-H}: grad_p = -tr S_p, Hess_pq = Re tr(S_p S_q)
            S1 = np.linalg.solve(C1, np.linalg.solve(C1, F1p).conj().transpose(0, 2, 1))
            S2 = np.linalg.solve(C2, np.linalg.solve(C2, F2p).conj().transpose(0, 2, 1))
            g = -(np.trace(S1, axis1=1, axis2=2).real + np.trace(S2, axis1=1, axis2=2).real)
            A1, A2 = S1.reshape(P, -1), S2.reshape(P, -1)
            H = (A1.conj() @ A1.T).real + (A2.conj() @ A2.T).real
            dy = -np.linalg.lstsq(H, g, rcond=1e-14)[0]
            dec2 = float(-g @ dy)  # squared Newton decrement
            if not (dec2 > 1e-16):
                break
            step = 1.0 if dec2 < 0.25 else 1.0 / (1.0 + np.sqrt(dec2))
            while step > 1e-10:
                phin, C1n, C2n = barrier(y + step * dy)
                if phin <= phi - 0.25 * step * dec2:
                    break
                step *= 0.5
            else:
                break
            y, phi, C1, C2 = y + step * dy, phin, C1n, C2n
            if dec2 < 1e-10:
                break
        X = X0 + np.tensordot(y, F2p, axes=1)
        G = G0 + (np.tensordot(y[nx:], Gb, axes=1) if ng else 0.0)
        try:  # back to the coordinates of Mn (X = T0^H X' T0, G = T0^H G' T0)
            xn = _x_from_scalings(T0.conj().T @ X @ T0, T0.conj().T @ G @ T0, lay, tpos,
                                  tfull, gpos, x.shape[0])
        except np.linalg.LinAlgError:
            break
        _, lamc = _eval(xn, Mn, kinds, offs, sizes, tpos, tfull, gpos, True, 0.0, gtmp)
        # round-off of lambda_max(H), H = M_T^H M_T + j(Gt M_T - M_T^H Gt)
        Tn, Tni = _build_T(xn, offs, sizes, tpos, tfull, n)
        MTn = Tn @ Mn @ Tni
        Gtn = Tni.conj().T @ _build_G(xn, offs, sizes, kinds, gpos, n) @ Tni
        err = 1e-13 * n * (np.linalg.norm(MTn, 2) ** 2 + 2 * np.linalg.norm(Gtn @ MTn, 2))
        if not (np.isfinite(lamc) and lamc > 10.0 * err):
            break
        if lamc < best_lam:
            best_x, best_lam = xn, float(lamc)
        if not (lamc < lev) or lev - lamc <= rtol * lamc:
            break
        lev = (1.0 - theta) * lamc + theta * lev  # the center stays strictly feasible
    return best_x, best_lam


def _lower_bound(search, Mi, Mn, lay, xb, tpos, tfull, has_real, all_real, upper,
                 seed, n_restarts, vertex_limit):
    kinds, offs, sizes = lay.kinds, lay.offs, lay.sizes
    n = lay.n
    target = upper * (1.0 - 1e-9)  # stop searching once the bounds meet
    # starts 0, 1: singular vectors of the optimally scaled matrix M_T = T M T^{-1}
    # (M_T v = s u  =>  M (T^{-1} v) = s T^{-1} u  and  M^H (T^H u) = s T^H v)
    T, Ti = _build_T(xb, offs, sizes, tpos, tfull, n)

    def gen_starts():  # lazily: most problems stop after the first start
        if np.isfinite(T).all() and np.isfinite(Ti).all():
            U, S, Vh = np.linalg.svd(T @ Mn @ Ti)
            v = Vh[0].conj()
            yield Ti @ v, T.conj().T @ v
            yield Ti @ U[:, 0], T.conj().T @ U[:, 0]
        U, S, Vh = np.linalg.svd(Mn)
        yield Vh[0].conj(), U[:, 0]
        rng = np.random.default_rng(seed)
        for _ in range(n_restarts):
            yield (rng.standard_normal(n) + 1j * rng.standard_normal(n),
                   rng.standard_normal(n) + 1j * rng.standard_normal(n))

    starts = []

    real_dirs = []
    kinds_c = np.where(kinds == _REAL, _CSCALAR, kinds).astype(np.int64)
    ridx_blocks = [i for i, k in enumerate(kinds) if k == _REAL]
    for b0, l0 in gen_starts():
        if search.best_est >= target:
            break
        starts.append((b0, l0))
        beta, a, b, l = _power_c(Mn, kinds, offs, sizes, b0, l0, 300, 1e-11)
        if beta > 0.0:
            Q, qn = _build_Q(kinds, offs, sizes, a, l, n)
            _offer_Q(search, Q, qn, Mi, has_real, "power iteration")
            if has_real:
                real_dirs.append(np.array([Q[offs[i], offs[i]].real for i in ridx_blocks]))
        if has_real:
            # complex relaxation of the real blocks: its phases suggest real directions
            beta, a, b, l = _power_c(Mn, kinds_c, offs, sizes, b0, l0, 300, 1e-11)
            if beta > 0.0:
                Qc, _ = _build_Q(kinds_c, offs, sizes, a, l, n)
                ph = np.array([Qc[offs[i], offs[i]] for i in ridx_blocks])
                real_dirs.append(np.where(ph.real >= 0, 1.0, -1.0))
                if np.max(np.abs(ph.real)) > 0:
                    real_dirs.append(ph.real / np.max(np.abs(ph.real)))
    if search.best_est < target:
        # Δ = z I is in every structure: spectral radius (complex) / largest real eigenvalue
        _offer_Q(search, np.eye(n, dtype=np.complex128), 1.0, Mi, has_real, "delta = z I")
    if not has_real or search.best_est >= target:
        return
    nreal = len(ridx_blocks)
    vlim = vertex_limit if all_real else min(vertex_limit, 3)
    if nreal <= vlim:
        for signs in product((1.0, -1.0), repeat=nreal - 1):
            real_dirs.append(np.array((1.0,) + signs))
    # deduplicate; q and -q are both searched (alpha > 0 on each)
    uniq = []
    for q in real_dirs:
        q = q * (1.0 if q[np.argmax(np.abs(q))] > 0 else -1.0)
        if not any(np.allclose(q, u2) for u2 in uniq):
            uniq.append(q)
    for q in uniq:
        for sgn in (1.0, -1.0):
            if search.best_est >= target:
                return
            _ray_search(search, Mi, lay, sgn * q, upper, starts[:2])


def _ray_search(search, Mi, lay, q, upper, starts):
    """Gain search along delta_real = alpha * q (Young & Doyle style real direction)."""
    kinds, offs, sizes = lay.kinds, lay.offs, lay.sizes
    n = lay.n
    ridx = np.concatenate([np.arange(o, o + s) for o, s, k in zip(offs, sizes, kinds) if k == _REAL])
    qfull = np.concatenate([np.full(s, qq) for qq, s in
                            zip(q, [s for s, k in zip(sizes, kinds) if k == _REAL])])
    Qr = np.diag(qfull).astype(np.complex128)
    # purely real loop singularities: positive real eigenvalues of M_rr Q_r (complex blocks 0)
    Mrr = Mi[np.ix_(ridx, ridx)]
    alpha_R = np.inf
    for lam in _eig_candidates(Mrr @ Qr, True)[:3]:
        lam = lam.real
        D = np.zeros((n, n), dtype=np.complex128)
        D[np.ix_(ridx, ridx)] = Qr / lam
        search.offer(D, abs(lam) / np.max(np.abs(q)), "real direction")
        if lam > 0:
            alpha_R = min(alpha_R, 1.0 / lam)
    cidx = np.array([i for i in range(n) if i not in set(ridx.tolist())], dtype=np.int64)
    if cidx.size == 0:
        return
    # complex sub-structure
    ck, co, cs = [], [], []
    o = 0
    for k, s in zip(kinds, sizes):
        if k != _REAL:
            ck.append(k)
            co.append(o)
            cs.append(s)
            o += s
    ck = np.array(ck, dtype=np.int64)
    co = np.array(co, dtype=np.int64)
    cs = np.array(cs, dtype=np.int64)
    Mcc = Mi[np.ix_(cidx, cidx)]
    Mcr = Mi[np.ix_(cidx, ridx)]
    Mrc = Mi[np.ix_(ridx, cidx)]
    sub_starts = [(b0[cidx], l0[cidx]) for b0, l0 in starts]
    nr = ridx.size

    def h(alpha):
        A = np.eye(nr) - alpha * (Mrr @ Qr)
        try:
            Mc = Mcc + alpha * (Mcr @ Qr) @ np.linalg.solve(A, Mrc)
        except np.linalg.LinAlgError:
            return np.inf, None
        lb, Dc = _complex_lower(Mc, ck, co, cs, sub_starts, maxit=150, tol=1e-9)
        return alpha * lb - 1.0, Dc

    alpha_lo = 1.0 / upper
    alpha_hi = min(alpha_R, 1.0 / search.best_est if search.best_est > 0 else 1e3 * alpha_lo)
    if not alpha_hi > alpha_lo * (1 + 1e-9):
        return
    grid = np.geomspace(alpha_lo, alpha_hi * (1 - 1e-9), 10)
    prev = None
    for al in grid:
        hv, Dc = h(al)
        if hv >= 0.0:
            lo = prev if prev is not None else al
            hi = al
            best_D = (al, Dc)
            if prev is not None:
                for _ in range(40):
                    mid = 0.5 * (lo + hi)
                    hm, Dm = h(mid)
                    if hm >= 0.0:
                        hi = mid
                        best_D = (mid, Dm)
                    else:
                        lo = mid
                    if hi - lo <= 1e-10 * hi:
                        break
            al_b, Dc_b = best_D
            if Dc_b is not None:
                D = np.zeros((n, n), dtype=np.complex128)
                D[np.ix_(ridx, ridx)] = al_b * Qr
                D[np.ix_(cidx, cidx)] = Dc_b
                search.offer(D, 1.0 / al_b, "real-direction gain search")
            return
        prev = al


def _assemble(M, lay, x, tpos, tfull, gpos, c, upper, delta, lower, method, nev, blk_arr,
              det_res=0.0):
    """Map the internal scalings to the user's D_L (p×p), D_R (q×q), G (q×p)."""
    n = lay.n
    T, Ti = _build_T(x, lay.offs, lay.sizes, tpos, tfull, n)
    if not (np.isfinite(T).all() and np.isfinite(Ti).all()):
        T = np.eye(n, dtype=np.complex128)
    # normalise the common factor (D is defined up to a positive scalar; X = D^H D and G
    # scale together): |det| of the last block's T becomes 1
    o, sz = lay.offs[-1], lay.sizes[-1]
    f = float(np.abs(np.linalg.det(T[o:o + sz, o:o + sz]))) ** (1.0 / sz)
    if not (f > 0 and np.isfinite(f)):
        f = 1.0
    T = T / f
    # internal G is the LMI variable for Mn = c M: divide by c (and by f^2 with X)
    Gfull = (_build_G(x, lay.offs, lay.sizes, lay.kinds, gpos, n) / (c * f * f)
             if (lay.kinds == _REAL).any() else np.zeros((n, n), dtype=np.complex128))
    if lay.square:
        return MuResult(
            upper=float(upper), lower=float(lower), delta=delta, d_left=T, d_right=T.copy(),
            g=Gfull, blk=blk_arr, det_residual=float(det_res),
            lower_method=method, n_evals=int(nev))
    d_left = T[np.ix_(lay.int_rows, lay.int_rows)]
    d_right = T[np.ix_(lay.int_cols, lay.int_cols)]
    # G lives on the real blocks, where the row and column index sets coincide
    g = Gfull[np.ix_(lay.int_cols, lay.int_rows)]
    return MuResult(
        upper=float(upper), lower=float(lower), delta=delta, d_left=d_left, d_right=d_right,
        g=g, blk=blk_arr, det_residual=float(det_res), lower_method=method, n_evals=int(nev),
    )
