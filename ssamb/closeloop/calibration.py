r"""Nominal-parameter calibration: the model's own parameters, estimated from the rig's data.

A rig never matches its nominal model: the rotor is heavier than drawn, the airgap ground a few
micrometres wide, the supply a volt low. These parameters are the first thing to estimate, and
effects come second (:mod:`ssamb.closeloop.search`). Each calibratable parameter is a dotted
config key with a prior tolerance (config ``closeloop.calibration``):

.. math:: \theta_i = \frac{p_i - p_{i,0}}{p_{i,0}} \sim N(0, \sigma_i^2)

(relative; a key whose nominal value is 0 -- a calibration offset -- is absolute,
:math:`\theta_i = p_i`). The estimate is the maximum a posteriori point of the feature residual
and the prior (:func:`ssamb.closeloop.estimate.map_fit`), with the posterior covariance from
the Jacobian at the optimum.

Identifiability (:func:`identifiability`) is read off the same Jacobian. With the data
information :math:`\mathcal I` (p x p) and the prior precision :math:`\Lambda`, the posterior
covariance is :math:`(\mathcal I + \Lambda)^{-1}`. A parameter is **identified** when the data
shrink its tolerance at least ``1/identifiable_ratio`` times (posterior standard deviation
:math:`\le` ``identifiable_ratio`` :math:`\sigma_i`). Otherwise the reason is computed:

* *no sensitivity* when even alone (all others known) the data would fix it no better than
  that, :math:`\mathcal I_{ii}^{-1/2} > r\sigma_i`;
* *confounded* when alone it would be identified but jointly it is not: the parameters it is
  most correlated with in the posterior are named (e.g. rotor mass and coil turns on an axis
  whose dynamics depend only on :math:`k_i/m`).

The scaled sensitivity matrix :math:`S = \mathcal I^{1/2}\,\mathrm{diag}(\sigma)` (information
per tolerance) gives the rank (singular values above 3: combinations known to a third of their
tolerance), the condition number, and the identified combinations.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .estimate import EstimateSettings, MapFit, Problem, _inverse, best_fit

__all__ = ["ParameterSpec", "parameter_specs", "bounded", "overrides_of", "calibration_problem", "identifiability",
           "findings", "Calibration", "calibrate_model"]


def _get(cfg: Mapping, key: str):
    node = cfg
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            raise KeyError(key)
        node = node[part]
    return node


@dataclass(frozen=True)
class ParameterSpec:
    """A calibratable parameter: dotted config key, nominal value and prior tolerance.

    ``relative`` parameters are :math:`p = p_0 (1 + \\theta)`, absolute ones :math:`p = \\theta`
    (nominal 0); ``prior_sd`` is in :math:`\\theta` units. ``lower``/``upper`` (in the parameter's
    own unit, optional) are hard limits the data imply (:meth:`ssamb.device.Device.calibration_bounds`).
    """

    key: str
    nominal: float
    relative: bool
    prior_sd: float
    lower: float | None = None
    upper: float | None = None

    def value(self, theta: float) -> float:
        return self.nominal * (1.0 + theta) if self.relative else self.nominal + theta

    def theta_of(self, value: float) -> float:
        return value / self.nominal - 1.0 if self.relative else value - self.nominal


def parameter_specs(cfg: Mapping, tolerances: Mapping[str, float]) -> list[ParameterSpec]:
    """The calibratable parameters: ``tolerances`` maps dotted keys to prior standard deviations.

    The specs are in the order of ``tolerances``; :func:`ssamb.closeloop.settings.settings_from_config`
    gives the canonical one (:func:`ssamb.closeloop.settings.canonical_order`: the estimator's
    design gives each position its own perturbation pattern).

    Raises
    ------
    ssamb.config.ConfigError
        A key that is not a numeric config value (named).
    """
    from ..config import ConfigError

    out = []
    for key, sd in tolerances.items():
        try:
            v = _get(cfg, key)
        except KeyError:
            raise ConfigError(f"config key 'closeloop.calibration.{key}': not a key of the model's config") from None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ConfigError(f"config key 'closeloop.calibration.{key}': '{key}' is not a number")
        if not (isinstance(sd, (int, float)) and math.isfinite(sd) and sd > 0):
            raise ConfigError(f"config key 'closeloop.calibration.{key}': the tolerance must be a number > 0")
        out.append(ParameterSpec(key, float(v), float(v) != 0.0, float(sd)))
    return out


def bounded(specs: list[ParameterSpec], bounds: Mapping[str, tuple]) -> list[ParameterSpec]:
    """``specs`` with the hard limits ``bounds`` (key -> ``(lower, upper)``, either None) the data
    imply (:meth:`ssamb.device.Device.calibration_bounds`), tightening any already set."""
    import dataclasses

    out = []
    for s in specs:
        lo, hi = bounds.get(s.key, (None, None))
        if lo is not None and s.lower is not None:
            lo = max(lo, s.lower)
        if hi is not None and s.upper is not None:
            hi = min(hi, s.upper)
        out.append(dataclasses.replace(s, lower=s.lower if lo is None else float(lo),
                                       upper=s.upper if hi is None else float(hi)))
    return out


def overrides_of(specs: list[ParameterSpec], theta: np.ndarray) -> dict:
    """Config overrides of a parameter vector."""
    return {s.key: s.value(float(t)) for s, t in zip(specs, theta)}


def calibration_problem(specs: list[ParameterSpec], residual, seed0: int = 1, start=None, groups=None,
                        max_step_rel: float = 0.05) -> Problem:
    """The :class:`~ssamb.closeloop.estimate.Problem` of the parameters.

    ``residual(overrides, seed)`` returns the whitened feature residual of the replay with
    those overrides. Finite-difference steps are one tolerance, at most ``max_step_rel`` of the
    nominal value (a smaller step leaves weak sensitivities in the replay's noise, a larger one
    reaches where the response is no longer linear: a wide tolerance like the iron's
    permeability); the bounds keep every parameter within 5 tolerances of its nominal value (and
    positive).
    """
    sd = np.array([s.prior_sd for s in specs])
    lo = np.array([max(-5 * s.prior_sd, -0.9) if s.relative else -5 * s.prior_sd for s in specs])
    hi = 5 * sd
    for j, s in enumerate(specs):          # the limits the data imply, within the prior's
        if s.upper is not None:
            hi[j] = min(hi[j], s.theta_of(s.upper))
        # an upper limit below the nominal value keeps five tolerances of room under it, but
        # never past a lower limit the data imply, nor a relative parameter's -90 %
        floor = s.theta_of(s.lower) if s.lower is not None else (-0.9 if s.relative else -np.inf)
        lo[j] = max(min(lo[j], hi[j] - 5 * sd[j]), floor)
    return Problem(names=tuple(s.key for s in specs), theta0=np.zeros(len(specs)), prior_sd=sd,
                   step=np.array([min(x.prior_sd, max_step_rel) if x.relative else x.prior_sd for x in specs]),
                   lower=lo, upper=hi,
                   evaluate=(lambda th, seed: residual(overrides_of(specs, th), seed)) if residual else None,
                   start=start, seed0=seed0, groups=groups)


@dataclass
class Calibration:
    """Calibrated nominal parameters.

    Attributes
    ----------
    specs : list of ParameterSpec
    fit : MapFit or None
        None when no parameter is calibrated.
    ident : dict
        :func:`identifiability` of the estimate.
    conflicts : list of str
        Parameters whose estimate lies more than ``conflict_z`` tolerances from nominal: the data
        contradict the stated tolerance (often an effect the model lacks, which the parameter
        absorbs; the effect search starts with them at their nominal value).
    restarts : list of dict
        With several fits (:func:`ssamb.closeloop.estimate.best_fit`), each one's score, the kept
        one first; empty with one.
    """

    specs: list
    fit: MapFit | None
    ident: dict
    conflicts: list
    restarts: list = dataclasses.field(default_factory=list)

    @property
    def theta(self) -> np.ndarray:
        return np.zeros(len(self.specs)) if self.fit is None else self.fit.theta

    def overrides(self, reset_conflicts: bool = False) -> dict:
        th = self.theta.copy()
        if reset_conflicts:
            for i, s in enumerate(self.specs):
                if s.key in self.conflicts:
                    th[i] = 0.0
        return overrides_of(self.specs, th)


def calibrate_model(cmp, specs: list[ParameterSpec], effects: list, settings: EstimateSettings, ratio: float,
                    conflict_z: float, seed0: int = 1, start=None, log=None, step_rel: float = 0.05,
                    restarts: int = 1) -> Calibration:
    """MAP calibration of ``specs`` on the fitting part of ``cmp`` (a
    :class:`~ssamb.closeloop.comparison.Comparison`) with ``effects`` in the model
    (finite-difference steps at most ``step_rel`` of a relative parameter's nominal value; the
    best of ``restarts`` fits, :func:`ssamb.closeloop.estimate.best_fit`)."""
    if not specs:
        return Calibration(specs, None, {"per_parameter": {}, "rank": 0, "n_parameters": 0, "condition": 1.0,
                                         "singular_values": [], "combinations": []}, [])

    def build(theta):
        return overrides_of(specs, theta), list(effects)
    prob = calibration_problem(specs, None, seed0=seed0, start=start, groups=cmp.groups(cmp.fit), max_step_rel=step_rel)
    prob.evaluate = cmp.evaluator(cmp.fit, build)
    prob.evaluate_many = cmp.evaluate_many(cmp.fit, build)
    if start is not None and hasattr(cmp.device, "start_candidates"):
        prob.start = _best_start(cmp, specs, prob, np.asarray(start, float), settings)
    fit, scores = best_fit(prob, settings, restarts, log)
    sd = np.array([s.prior_sd for s in specs])
    ident = identifiability(fit.info, sd, tuple(s.key for s in specs), ratio, cov=fit.cov,
                            relative=tuple(s.relative for s in specs))
    conflicts = [s.key for s, t in zip(specs, fit.theta) if abs(t) > conflict_z * s.prior_sd]
    return Calibration(specs, fit, ident, conflicts, scores)


def _best_start(cmp, specs: list[ParameterSpec], prob, start: np.ndarray, settings: EstimateSettings) -> np.ndarray:
    """The start among ``start`` and the device's candidates about it (optional
    ``Device.start_candidates(record, cfg, overrides)``: models the data's start estimate cannot
    tell apart) whose ``centre_runs`` replays on the fitting part drop the body least, then fit
    it best (:func:`ssamb.closeloop.estimate.drops_and_cost`; the fitting data only)."""
    from .estimate import drops_and_cost

    cands = cmp.device.start_candidates(cmp.record, cmp.replay.cfg, overrides_of(specs, start)) or []
    keys = [sp.key for sp in specs]
    thetas = [start] + [np.clip([sp.theta_of(c[sp.key]) if sp.key in c else t for sp, t in zip(specs, start)],
                                prob.lower, prob.upper) for c in cands if set(c) <= set(keys)]
    if len(thetas) == 1:
        return start
    score = [drops_and_cost(prob.batch([(th, prob.seed0 + 650_500 + j) for j in range(settings.centre_runs)]))
             for th in thetas]
    return thetas[min(range(len(thetas)), key=lambda j: score[j])]


def identifiability(info: np.ndarray, prior_sd: np.ndarray, names: tuple, ratio: float,
                    cov: np.ndarray | None = None, cov_noise: np.ndarray | None = None,
                    relative: tuple | None = None) -> dict:
    r"""Which parameters the data identify, and why not the others (module docstring).

    Parameters
    ----------
    info : numpy.ndarray
        Data information (p x p) in parameter units (:attr:`MapFit.info`).
    prior_sd : numpy.ndarray
        Prior standard deviations (``inf``: none -- an effect's parameter).
    names : tuple of str
    ratio : float
        ``identifiable_ratio``.
    cov : numpy.ndarray, optional
        Posterior covariance of the estimate (:attr:`MapFit.cov`, which holds the noise the
        replicates measured); default :math:`(\mathcal I + \Lambda)^{-1}`.
    cov_noise : numpy.ndarray, optional
        When ``cov`` is the covariance with the model's misfit (:attr:`MapFit.cov_misfit`),
        the one at the noise alone: a parameter identified by this one but not by ``cov`` is
        reported as lost to the misfit.
    relative : tuple of bool, optional
        Per parameter, whether it is relative to its nominal value (the reasons quote its
        uncertainties in per cent) or absolute (in its own unit); default all relative.

    Returns
    -------
    dict
        ``per_parameter`` (name -> identified, se, se_alone, tolerance, partner, correlation,
        reason), ``rank``, ``condition``, ``singular_values``, ``combinations``.
    """
    lam = np.where(np.isfinite(prior_sd), 1.0 / np.where(np.isfinite(prior_sd), prior_sd, 1.0) ** 2, 0.0)
    alone = 1.0 / np.sqrt(np.maximum(np.diag(info), 1e-300))
    scale = np.where(np.isfinite(prior_sd), prior_sd, np.minimum(alone, 1e150))
    joint = _inverse(info + np.diag(lam), scale)          # what the information alone implies
    cov = joint if cov is None else cov
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    sj = np.sqrt(np.maximum(np.diag(joint), 1e-300))
    corr = joint / np.outer(sj, sj)
    S = info * np.outer(scale, scale)
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    sv = np.sqrt(np.maximum(w[::-1], 0.0))
    V = V[:, ::-1]
    per = {}
    rel = tuple(relative) if relative is not None else (True,) * len(names)
    for i, name in enumerate(names):
        tol = float(prior_sd[i])
        fmt = _pct if rel[i] else _abs
        c = corr[i].copy()
        c[i] = 0.0
        j = int(np.argmax(np.abs(c)))
        ident = bool(se[i] <= ratio * tol) if math.isfinite(tol) else bool(se[i] < 1e5 * alone[i])
        per[name] = {"identified": ident, "se": float(se[i]), "se_alone": float(alone[i]), "tolerance": tol,
                     "partner": names[j] if len(names) > 1 else None,
                     "correlation": float(c[j]) if len(names) > 1 else 0.0,
                     "reason": None if ident else _reason(i, names, c, alone[i], se[i], tol, ratio, fmt)}
        if (not ident and cov_noise is not None and math.isfinite(tol)
                and np.sqrt(max(cov_noise[i, i], 0.0)) <= ratio * tol):
            per[name]["reason"] = (f"the model misfits the data beyond their noise: with the misfit it is known only "
                                   f"to +-{fmt(se[i])} (+-{fmt(float(np.sqrt(cov_noise[i, i])))} at the noise alone; "
                                   f"tolerance +-{fmt(tol)})")
    combos = []
    for k in range(len(sv)):
        if sv[k] < 3.0:
            break
        v = V[:, k] / np.max(np.abs(V[:, k]))
        terms = {names[i]: float(v[i]) for i in np.argsort(-np.abs(v)) if abs(v[i]) >= 0.1}
        combos.append({"weights": terms, "known_to_fraction_of_tolerance": float(1.0 / sv[k])})
    return {"per_parameter": per, "rank": int(np.sum(sv >= 3.0)), "n_parameters": len(names),
            "condition": _condition(sv),
            "singular_values": sv.tolist(), "combinations": combos}


def _condition(sv: np.ndarray) -> float | None:
    """Condition number of the singular values ``sv`` (descending); None when the smallest is
    at round-off level of the largest (numerically singular: a ratio like 1e304 means nothing)."""
    if not len(sv):
        return 1.0
    if sv[-1] <= len(sv) * np.finfo(float).eps * sv[0]:
        return None
    return float(sv[0] / sv[-1])


def _reason(i: int, names: tuple, c: np.ndarray, alone: float, se: float, tol: float, ratio: float,
            fmt=None) -> str:
    """Why parameter ``i`` is not identified: no sensitivity, or the parameters it trades off with
    (uncertainties written by ``fmt``: per cent of the nominal value, or absolute)."""
    _pct = fmt or globals()["_pct"]
    if not math.isfinite(tol):
        return "the estimate did not move along a direction the data determine (no reliable sensitivity)"
    if alone > ratio * tol:
        return (f"the data barely depend on it: even alone it would be known to +-{_pct(alone)} "
                f"(tolerance +-{_pct(tol)})")
    order = [k for k in np.argsort(-np.abs(c)) if k != i]
    if not order:
        return (f"the data inform it (alone it would be known to +-{_pct(alone)}), but the estimate did not move "
                f"along it: its sensitivity is below the replays' noise (tolerance +-{_pct(tol)})")
    strong = [names[k] for k in order[:2] if abs(c[k]) >= 0.5]
    if strong:
        who = f"confounded with {' and '.join(strong)} (posterior correlation {c[order[0]]:+.2f})"
    else:
        who = (f"confounded with a combination of several parameters ({', '.join(names[k] for k in order[:3])}; "
               f"none alone correlates beyond {abs(c[order[0]]):.2f})")
    return f"{who}: alone it would be known to +-{_pct(alone)}, jointly only to +-{_pct(se)} (tolerance +-{_pct(tol)})"


def _pct(x: float) -> str:
    return f"{100 * x:.2g} %"


def _abs(x: float) -> str:
    """An absolute parameter's uncertainty, in its own unit (the unit its config key names)."""
    return f"{x:.2g}"


def findings(specs: list[ParameterSpec], theta: np.ndarray, ident: dict) -> tuple[dict, dict]:
    """``closeloop.json``'s ``parameters`` (identified) and ``not_identifiable`` (with reasons)."""
    params, not_ident = {}, {}
    for s, t in zip(specs, theta):
        d = ident["per_parameter"][s.key]
        if d["identified"]:
            value = s.value(float(t))
            se = d["se"] * (abs(s.nominal) if s.relative else 1.0)
            params[s.key] = {"value": value, "se": se, "nominal": s.nominal,
                             "relative_change": float(t) if s.relative else None,
                             "change": value - s.nominal, "identifiable": True,
                             "tolerance": s.prior_sd * (abs(s.nominal) if s.relative else 1.0)}
        else:
            not_ident[s.key] = d["reason"]
    return params, not_ident
