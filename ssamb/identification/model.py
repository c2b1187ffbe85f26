r"""The identified model: an affine discrete-time state-space model with its operating point,
simulation, k-step prediction and validation fit (see :mod:`ssamb.identification`)."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from ..channels import ONE
from .data import _as_2d, nrmse_fit


def _spectral_radius(A) -> float:
    A = np.asarray(A, dtype=float)
    return float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0


def _simulate(A, B, C, D, w, x0):
    """States (N, n) and outputs (N, l) of x+ = A x + B w, y = C x + D w from x0."""
    from ..lsim import dlsim

    return dlsim(A, B, C, D, w, x0)


_KERNELS: dict = {}


def _state_regressors_kernel():
    """The compiled recursion of :func:`_state_regressors` (numba, compiled once per process
    and cached on disk): explicit loops, no temporaries in the time loop."""
    if "state" not in _KERNELS:
        import numba  # imported where needed: jobs that never refine a model do not pay for it

        @numba.njit(cache=True)
        def state(F, C, w, out):  # pragma: no cover - compiled
            n = F.shape[0]
            N, q = w.shape
            l_ = C.shape[0]
            Z = np.zeros((n, n * q))
            Znew = np.zeros((n, n * q))
            for t in range(N):
                for a in range(l_):
                    for c in range(n * q):
                        acc = 0.0
                        for i in range(n):
                            acc += C[a, i] * Z[i, c]
                        out[t, a, c] = acc
                for i in range(n):
                    for c in range(n * q):
                        acc = 0.0
                        for m in range(n):
                            acc += F[i, m] * Z[m, c]
                        Znew[i, c] = acc
                for j in range(n):
                    for k in range(q):
                        Znew[j, j * q + k] += w[t, k]
                Z, Znew = Znew, Z

        _KERNELS["state"] = state
    return _KERNELS["state"]


def _state_regressors(F, C, w):
    r"""Output responses to unit entries of the input matrix.

    Returns ``R`` of shape (N, l, n, q) with
    :math:`R_{t,:,j,k} = \sum_{s<t} C F^{t-1-s} e_j w_{s,k}`, i.e. the derivative of the
    output of :math:`x^+ = F x + G w` with respect to :math:`G_{jk}`. The state responses
    :math:`Z_t` (n, n, q) follow :math:`Z_{t+1} = F Z_t + e_j w_{t,k}` and
    :math:`R_t = C Z_t`: a compiled loop over the N samples (a NumPy loop pays its
    per-call overhead on matrices of a few dozen entries at every sample).
    """
    F = np.ascontiguousarray(F, dtype=float)
    C = np.ascontiguousarray(C, dtype=float)
    w = np.ascontiguousarray(w, dtype=float)
    n = F.shape[0]
    N, q = w.shape
    out = np.zeros((N, C.shape[0], n * q))
    if n and N:
        _state_regressors_kernel()(F, C, w, out)
    return out.reshape(N, C.shape[0], n, q)


def _obs_regressors(F, C, N):
    """(N, l, n): C F^t for t = 0..N-1 (the free response to each initial-state entry)."""
    n = F.shape[0]
    out = np.empty((N, C.shape[0], n))
    M = np.array(C, dtype=float)
    with np.errstate(all="ignore"):
        for t in range(N):
            out[t] = M
            M = M @ F
    return out


def _predictor_gain(A, C, K=None):
    """A predictor gain K with A - K C stable: the given one if it works, else a DARE design.

    The fallback is the steady-state Kalman gain for unit process noise on every state and
    measurement noise ``C C^T`` (noise comparable to a unit state seen at the output): a
    generic observer for models whose identification gave no usable K.
    """
    n = A.shape[0]
    if K is not None:
        K = np.asarray(K, dtype=float)
        if K.shape == (n, C.shape[0]) and np.all(np.isfinite(K)) and _spectral_radius(A - K @ C) < 1:
            return K
    R = C @ C.T
    R = R + 1e-9 * max(np.trace(R), 1e-300) * np.eye(C.shape[0])
    P = scipy.linalg.solve_discrete_are(A.T, C.T, np.eye(n), R)
    return A @ P @ C.T @ np.linalg.inv(C @ P @ C.T + R)


def auto_horizon(A, n_samples: int) -> int | None:
    r"""Validation horizon: ``None`` (pure simulation) for a stable :math:`A`, otherwise
    :math:`k = \lceil 1/\ln \rho(A) \rceil` samples (the e-folding time of the fastest
    unstable mode), clipped to ``[1, n_samples]``."""
    rho = _spectral_radius(A)
    if rho < 1.0:
        return None
    if rho == 1.0:
        return int(n_samples)
    return int(min(max(math.ceil(1.0 / math.log(rho)), 1), n_samples))


# ----------------------------------------------------------------------------------------
# the model
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class IdentifiedModel:
    r"""A discrete-time (affine) state-space model identified from data.

    Attributes
    ----------
    A, B, C, D : ndarray
        State-space matrices. If ``affine``, the last columns of ``B`` and ``D`` are
        :math:`b_1`, :math:`d_1` of the constant input ``one`` (see the module docstring).
    dt : float
        Sampling period, s.
    method : str
        SIPPY method.
    input_names, output_names : tuple of str
        Physical channel names (without ``one``).
    affine : bool
        Whether the model has the operating-point input ``one``.
    u_op, y_op : ndarray
        Operating point: input about which the data were taken (the data mean) and the model's
        equilibrium output there.
    K : ndarray or None
        One-step predictor (Kalman) gain, (n, l), for prediction of unstable models.
    data_hash : str
        :func:`data_hash` of the estimation data.
    ss_f, ss_p : int
        SIPPY future and past horizons.
    info : dict
        Diagnostics: SIPPY messages, time, excitation, refinement, estimation fit ...
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float
    method: str
    input_names: tuple
    output_names: tuple
    affine: bool = True
    u_op: np.ndarray = None
    y_op: np.ndarray = None
    K: np.ndarray | None = None
    data_hash: str = ""
    ss_f: int = 0
    ss_p: int = 0
    info: dict = field(default_factory=dict, compare=False)

    # ---- shapes and names -------------------------------------------------------------
    @property
    def order(self) -> int:
        return int(self.A.shape[0])

    @property
    def fs_hz(self) -> float:
        return 1.0 / self.dt

    @property
    def n_inputs(self) -> int:
        """Number of physical inputs (without ``one``)."""
        return len(self.input_names)

    @property
    def all_input_names(self) -> tuple:
        """Input names of the state-space matrices (``one`` last if affine)."""
        return tuple(self.input_names) + ((ONE,) if self.affine else ())

    @property
    def spectral_radius(self) -> float:
        r""":math:`\max_i |\lambda_i(A)|`."""
        return _spectral_radius(self.A)

    @property
    def is_stable(self) -> bool:
        return self.spectral_radius < 1.0

    @property
    def poles(self) -> np.ndarray:
        return np.linalg.eigvals(self.A)

    def to_statespace(self, name: str | None = None):
        """A ``control.StateSpace`` (dt = 1/fs) with named inputs (``one`` last) and outputs."""
        import control

        return control.ss(self.A, self.B, self.C, self.D, self.dt, inputs=list(self.all_input_names),
                          outputs=list(self.output_names), name=name)

    # ---- inputs with the constant column ----------------------------------------------
    def _w(self, u) -> np.ndarray:
        u = _as_2d(u, "u")
        if u.shape[1] == len(self.all_input_names):
            return u
        if u.shape[1] != self.n_inputs:
            raise ValueError(f"u has {u.shape[1]} columns, the model has inputs {self.input_names}")
        if self.affine:
            return np.column_stack([u, np.ones(len(u))])
        return u

    def equilibrium(self, u_const=None):
        r"""Equilibrium for a constant input: :math:`x = (I - A)^{-1} B w`, :math:`y = C x + D w`.

        ``u_const`` defaults to the operating point ``u_op``. Raises ``LinAlgError`` if
        :math:`A` has an eigenvalue at 1 (no unique equilibrium).
        """
        u_const = self.u_op if u_const is None else np.asarray(u_const, float).ravel()
        w = self._w(u_const[None, :])[0]
        x = np.linalg.solve(np.eye(self.order) - self.A, self.B @ w)
        return x, self.C @ x + self.D @ w

    # ---- simulation, initial state, prediction, fit -----------------------------------
    def simulate(self, u, x0=None, return_states: bool = False):
        """Simulate the model.

        Parameters
        ----------
        u : array_like, (N, m) or (N, m+1)
            Physical inputs (the constant ``one`` column is appended if absent).
        x0 : None, 'steady', 'zero' or array (n,)
            Initial state; ``None``/'steady' is the equilibrium for ``u[0]`` held constant, so
            that data starting at the operating point show no start-up transient.

        Returns
        -------
        ndarray (N, l) of outputs, and the states (N, n) if ``return_states``.
        """
        w = self._w(u)
        if x0 is None or (isinstance(x0, str) and x0 == "steady"):
            x0 = self.equilibrium(w[0, : self.n_inputs])[0]
        elif isinstance(x0, str) and x0 == "zero":
            x0 = np.zeros(self.order)
        x, y = _simulate(self.A, self.B, self.C, self.D, w, np.asarray(x0, float).ravel())
        return (y, x) if return_states else y

    def estimate_x0(self, u, y, n_samples: int | None = 1000) -> np.ndarray:
        r"""Least-squares initial state on the first ``n_samples`` samples (fewer for an
        unstable model: at most :math:`30/\ln\rho(A)` samples, so that the regressors stay finite).

        .. math:: \hat x_0 = \arg\min_{x_0} \sum_{k < N_0}
                  \| y_k - y^{(0)}_k - C A^k x_0 \|^2

        with :math:`y^{(0)}` the model response from :math:`x_0 = 0` (``lstsq``, minimum norm
        for unobservable directions).
        """
        w = self._w(u)
        y = _as_2d(y, "y")
        N0 = len(w) if n_samples is None else int(min(max(n_samples, 1), len(w)))
        rho = self.spectral_radius
        if rho > 1.0:  # keep the growth of the unstable modes below e^30 over the window
            N0 = int(min(N0, max(self.order + 1, math.ceil(30.0 / math.log(rho)))))
        _, y_zero = _simulate(self.A, self.B, self.C, self.D, w[:N0], np.zeros(self.order))
        O = _obs_regressors(self.A, self.C, N0).reshape(N0 * self.C.shape[0], self.order)
        r = (y[:N0] - y_zero).reshape(-1)
        if not (np.all(np.isfinite(O)) and np.all(np.isfinite(r))):
            raise ValueError(f"estimate_x0: the model response is not finite over {N0} samples")
        scale = np.linalg.norm(O, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        sol, *_ = np.linalg.lstsq(O / scale, r, rcond=None)
        return sol / scale

    def predictor_gain(self) -> np.ndarray:
        """The model's K if :math:`A - KC` is stable, otherwise a generic DARE observer."""
        return _predictor_gain(self.A, self.C, self.K)

    def predict(self, u, y, horizon: int, x0=None) -> np.ndarray:
        r""":math:`k`-step-ahead prediction :math:`\hat y(t \mid t-k)` (MATLAB ``compare(.., k)``).

        The one-step predictor :math:`\hat x_{t+1} = A\hat x_t + B w_t + K(y_t - C\hat x_t - D w_t)`
        runs over the data; each prediction then propagates its state :math:`k-1` steps with the
        model alone. The first :math:`k-1` samples are the simulation from ``x0`` (default:
        least squares on the first samples).
        """
        w = self._w(u)
        y = _as_2d(y, "y")
        k = int(horizon)
        if k < 1:
            raise ValueError(f"horizon must be >= 1 (got {horizon})")
        if x0 is None:
            x0 = self.estimate_x0(u, y)
        x0 = np.asarray(x0, float).ravel()
        K = self.predictor_gain()
        A, B, C, D = self.A, self.B, self.C, self.D
        N, q = w.shape
        l_ = C.shape[0]
        xp, _ = _simulate(A - K @ C, np.hstack([B - K @ D, K]), C, np.hstack([D, np.zeros((l_, y.shape[1]))]),
                          np.hstack([w, y]), x0)
        k = min(k, N)
        yhat = np.empty_like(y)
        if k > 1:
            yhat[: k - 1] = _simulate(A, B, C, D, w[: k - 1], x0)[1]
        # y(t|t-k) = C A^(k-1) x(t-k+1|t-k) + sum_{i=1}^{k-1} C A^(i-1) B w(t-i) + D w(t)
        taps = np.zeros((k, l_, q))
        M = C.copy()
        with np.errstate(all="ignore"):
            for i in range(1, k):
                taps[i] = M @ B
                M = M @ A
            import scipy.signal

            fir = scipy.signal.fftconvolve(w[:, None, :], taps, axes=0)[:N].sum(axis=2)
            yhat[k - 1:] = xp[: N - k + 1] @ M.T + fir[k - 1:] + w[k - 1:] @ D.T
        return yhat

    def fit(self, u, y, horizon="auto", x0="ls") -> np.ndarray:
        """Per-channel :func:`nrmse_fit` on data ``(u, y)``.

        ``horizon``: None = simulation, int = k-step prediction, 'auto' = :func:`auto_horizon`.
        ``x0``: 'ls' (:meth:`estimate_x0`), 'steady', 'zero' or an array.
        """
        y = _as_2d(y, "y")
        if horizon == "auto":
            horizon = auto_horizon(self.A, len(y))
        if isinstance(x0, str) and x0 == "ls":
            x0 = self.estimate_x0(u, y)
        if horizon is None:
            yhat = self.simulate(u, x0=x0)
        else:
            if isinstance(x0, str):
                x0 = self.simulate(np.asarray(u)[:1], x0=x0, return_states=True)[1][0]
            yhat = self.predict(u, y, horizon, x0=x0)
        return nrmse_fit(y, yhat)

    def replace(self, **changes) -> "IdentifiedModel":
        return dataclasses.replace(self, **changes)

