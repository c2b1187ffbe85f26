r"""Order selection and method comparison: validation fit against order and SIPPY method,
and the subspace singular values (the evidence for the paper's orders 9, 7 and 3)."""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..io import DataError
from .data import FS_HZ_DEFAULT, _as_2d, _names, check_io_data
from .memo import identification_memo
from .model import IdentifiedModel, auto_horizon
from .subspace import arx_equilibrium, identify

_SIM_METHODS = ("N4SID", "MOESP", "CVA")


def subspace_singular_values(u, y, method: str = "N4SID", ss_f: int = 30, ss_p: int = 30) -> np.ndarray:
    r"""Singular values of SIPPY's weighted SVD step (the order evidence).

    The data are centred as in :func:`identify` (input mean, output equilibrium from
    :func:`arx_equilibrium`) and scaled per channel as SIPPY does before its SVD; for
    N4SID/MOESP/CVA this calls ``OLSims_methods.SVD_weighted``; for PARSIM-K the predictor
    Markov-parameter matrix :math:`\Gamma_L` is built with SIPPY's own helpers and
    ``SVD_weighted_K`` applied. A gap after the n-th value suggests order n.
    """
    u, y, _, _ = check_io_data(u, y, None, None, ss_f, ss_p)
    from sippy_unipi import OLSims_methods, Parsim_methods
    from sippy_unipi.functionsetSIM import impile, ordinate_sequence

    try:
        y_c = arx_equilibrium(u, y, ss_p)
    except (np.linalg.LinAlgError, DataError):
        y_c = y.mean(0)
    uz = ((u - u.mean(0)) / u.std(0)).T.copy()
    yz = ((y - y_c) / np.where(y.std(0) > 0, y.std(0), 1.0)).T.copy()
    l_, m = yz.shape[0], uz.shape[0]
    with np.errstate(all="ignore"):
        if method in _SIM_METHODS:
            _, S, _, _, _ = OLSims_methods.SVD_weighted(yz, uz, int(ss_f), l_, method)
            return np.asarray(S)
        if method != "PARSIM-K":
            raise ValueError(f"singular values available for {_SIM_METHODS + ('PARSIM-K',)}, not {method}")
        f, p = int(ss_f), int(ss_p)
        Yf, Yp = ordinate_sequence(yz, f, p)
        Uf, Up = ordinate_sequence(uz, f, p)
        Zp = impile(Up, Yp)
        M = Yf[0:l_, :] @ np.linalg.pinv(impile(Zp, Uf[0:m, :]))
        Matrix_pinv = np.linalg.pinv(impile(Zp, impile(Uf[0:m, :], Yf[0:l_, :])))
        Gamma_L = M[:, 0:(m + l_) * f]
        H_K = M[:, (m + l_) * f:]
        G_K = np.zeros((l_, l_))
        for i in range(1, f):
            y_tilde = Parsim_methods.estimating_y(H_K, Uf, G_K, Yf, i, m, l_)
            M = (Yf[l_ * i: l_ * (i + 1)] - y_tilde) @ Matrix_pinv
            H_K = impile(H_K, M[:, (m + l_) * f:(m + l_) * f + m])
            G_K = impile(G_K, M[:, (m + l_) * f + m:])
            Gamma_L = impile(Gamma_L, M[:, 0:(m + l_) * f])
        _, S, _ = Parsim_methods.SVD_weighted_K(Uf, Zp, Gamma_L)
        return np.asarray(S)


def _split(u, y, u_val, y_val, val_fraction):
    u = _as_2d(u, "u")
    y = _as_2d(y, "y")
    if u_val is None:
        if y_val is not None:
            raise ValueError("give both u_val and y_val, or neither")
        n_est = int(round(len(u) * (1.0 - val_fraction)))
        return u[:n_est], y[:n_est], u[n_est:], y[n_est:]
    return u, y, _as_2d(u_val, "u_val"), _as_2d(y_val, "y_val")


@dataclass(frozen=True)
class OrderScan:
    """Result of :func:`order_scan`: validation fits (per channel) vs order."""

    orders: np.ndarray
    fits: np.ndarray  # (n_orders, l)
    mean_fit: np.ndarray  # (n_orders,)
    spectral_radius: np.ndarray  # (n_orders,)
    horizons: list  # validation horizon used per order (None = simulation)
    singular_values: np.ndarray | None
    method: str
    output_names: tuple
    errors: dict

    def smallest_order_within(self, tol_pct: float = 1.0) -> int:
        """Smallest order whose mean fit is within ``tol_pct`` of the best (parsimony)."""
        best = np.nanmax(self.mean_fit)
        ok = np.where(self.mean_fit >= best - tol_pct)[0]
        return int(self.orders[ok[0]])

    def as_dict(self) -> dict:
        return {"method": self.method, "orders": self.orders.tolist(), "fits": self.fits.tolist(),
                "mean_fit": self.mean_fit.tolist(), "spectral_radius": self.spectral_radius.tolist(),
                "horizons": self.horizons, "output_names": list(self.output_names),
                "singular_values": None if self.singular_values is None else self.singular_values.tolist(),
                "errors": self.errors}


def order_scan(u, y, orders=range(1, 16), method: str = "N4SID", fs_hz: float = FS_HZ_DEFAULT,
               input_names=None, output_names=None, *, u_val=None, y_val=None,
               val_fraction: float = 1 / 3, horizon="auto", singular_values: bool = True,
               **identify_kwargs) -> OrderScan:
    """Validation fit vs model order (evidence for the paper's orders 9, 7 and 3).

    Parameters
    ----------
    u, y : array_like
        Estimation data; if ``u_val``/``y_val`` are not given the last ``val_fraction`` of the
        record is held out for validation.
    orders : iterable of int
        Orders to try (each below ``ss_f``).
    horizon : None, int or 'auto'
        Validation horizon (see :meth:`IdentifiedModel.fit`); 'auto' simulates stable models
        and predicts unstable ones over their e-folding time.
    singular_values : bool
        Also return SIPPY's SVD singular values (:func:`subspace_singular_values`).
    **identify_kwargs
        Passed to :func:`identify` (``ss_f``, ``ss_p``, ``refine``, ...).
    """
    ue, ye, uv, yv = _split(u, y, u_val, y_val, val_fraction)
    orders = np.array(sorted(int(o) for o in orders))
    l_ = ye.shape[1]
    fits = np.full((len(orders), l_), np.nan)
    rho = np.full(len(orders), np.nan)
    horizons, errors = [], {}
    with identification_memo():  # the orders share everything up to SIPPY's SVD (exact)
        for i, n in enumerate(orders):
            try:
                mdl = identify(ue, ye, int(n), method, fs_hz, input_names, output_names, **identify_kwargs)
                h = auto_horizon(mdl.A, len(yv)) if horizon == "auto" else horizon
                fits[i] = mdl.fit(uv, yv, horizon=h)
                rho[i] = mdl.spectral_radius
                horizons.append(h)
            except (RuntimeError, np.linalg.LinAlgError, ValueError) as exc:
                if isinstance(exc, DataError):
                    raise
                errors[int(n)] = str(exc)
                horizons.append(None)
        sv = None
        if singular_values and method in _SIM_METHODS + ("PARSIM-K",):
            sv = subspace_singular_values(ue, ye, method, identify_kwargs.get("ss_f", 30),
                                          identify_kwargs.get("ss_p", 30))
    names = _names(output_names, l_, "y", "output_names")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean_fit = np.nanmean(np.where(np.isfinite(fits), fits, np.nan), axis=1)
    return OrderScan(orders, fits, mean_fit, rho, horizons, sv, method, names, errors)


@dataclass(frozen=True)
class MethodResult:
    """One method of :func:`compare_methods`."""

    method: str
    fit: np.ndarray | None  # per output channel, validation data
    mean_fit: float
    spectral_radius: float
    stable: bool
    horizon: int | None
    model: IdentifiedModel | None
    error: str | None = None

    def as_dict(self) -> dict:
        return {"method": self.method, "fit": None if self.fit is None else self.fit.tolist(),
                "mean_fit": self.mean_fit, "spectral_radius": self.spectral_radius,
                "stable": self.stable, "horizon": self.horizon, "error": self.error}


def compare_methods(u, y, order: int, methods=("N4SID", "MOESP", "CVA", "PARSIM-K"),
                    fs_hz: float = FS_HZ_DEFAULT, input_names=None, output_names=None, *,
                    u_val=None, y_val=None, val_fraction: float = 1 / 3, horizon="auto",
                    **identify_kwargs) -> list[MethodResult]:
    """Identify with each method at one order; validation fit and stability of each.

    A method that fails is reported with its ``error`` (and ``nan`` fits), not raised, so
    that one failure does not hide the others. Results are in the order of ``methods``; pick
    with ``max(results, key=lambda r: r.mean_fit)``.
    """
    ue, ye, uv, yv = _split(u, y, u_val, y_val, val_fraction)
    out = []
    with identification_memo():  # the methods share the operating point and SIPPY's projections (exact)
        for meth in methods:
            try:
                mdl = identify(ue, ye, order, meth, fs_hz, input_names, output_names, **identify_kwargs)
                h = auto_horizon(mdl.A, len(yv)) if horizon == "auto" else horizon
                fit = mdl.fit(uv, yv, horizon=h)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    mf = float(np.nanmean(fit))
                out.append(MethodResult(meth, fit, mf, mdl.spectral_radius, mdl.is_stable, h, mdl))
            except DataError:
                raise
            except Exception as exc:  # one failing method must not hide the others
                out.append(MethodResult(meth, None, math.nan, math.nan, False, None, None, str(exc)))
    return out



@dataclass(frozen=True)
class Selection:
    """The model :func:`compare_and_select` chose, with every method's result."""

    method: str
    model: IdentifiedModel
    results: list
    rule: str
    input_directions: np.ndarray | None


#: Subsystems that are stable systems (current loops, DCM as a filtered sensor): a stable
#: model is preferred; the plant is open-loop unstable and judged on its prediction fit alone.
STABLE_SUBSYSTEMS = ("amplifier", "selfsensing")


def compare_and_select(est, val, subsystem: str, variant: str | None, order: int, methods: Sequence[str],
                       fs_hz: float, **identify_kwargs) -> Selection:
    """Identify ``subsystem`` with every method at ``order`` and select the best validation fit
    (among the stable models for :data:`STABLE_SUBSYSTEMS`, when there is one).

    ``est``, ``val`` are :class:`~ssamb.identification.data.IOData` of the estimation and
    validation records. Raises ``RuntimeError`` (naming each method's error) if every method
    fails.
    """
    from ..channels import structure

    tdir = structure(subsystem, variant).input_directions
    results = compare_methods(est.u, est.y, order, methods=tuple(methods), fs_hz=fs_hz,
                              input_names=est.input_names, output_names=est.output_names,
                              u_val=val.u, y_val=val.y, input_directions=tdir, **identify_kwargs)
    ok = [r for r in results if r.model is not None and np.isfinite(r.mean_fit)]
    if not ok:
        raise RuntimeError(f"identify {subsystem}: every method failed: "
                           + "; ".join(f"{r.method}: {r.error}" for r in results))
    stable = [r for r in ok if r.stable] if subsystem in STABLE_SUBSYSTEMS else []
    best = max(stable or ok, key=lambda r: r.mean_fit)
    rule = "best validation fit among the stable models" if stable else "best validation fit"
    return Selection(best.method, best.model, results, rule, tdir)


def model_summary(sel: Selection, val, fs_hz: float) -> dict:
    """Evidence of a selected model: fits on the validation record, poles, methods compared."""
    model = sel.model
    fit = np.asarray(model.fit(val.u, val.y))
    poles = model.poles
    return {
        "order": model.order, "method": sel.method, "inputs": list(val.input_names),
        "outputs": list(val.output_names), "fit_pct": dict(zip(val.output_names, fit.tolist())),
        "mean_fit_pct": float(np.mean(fit)), "spectral_radius": model.spectral_radius,
        "stable": bool(model.is_stable),
        "poles_z": {"re": poles.real.tolist(), "im": poles.imag.tolist()},
        "poles_hz": (np.log(poles.astype(complex)) * fs_hz / (2 * np.pi)).real.tolist(),
        "methods": [r.as_dict() for r in sel.results], "selection": sel.rule, "fs_hz": fs_hz,
    }
