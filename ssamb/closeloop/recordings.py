r"""Close the loop over several recordings of one device: calibrate on some, judge on the others.

A rig's recordings share its physics but not their noise, their excitation or their mishaps (a
ball that drops in one log and floats in another). Each **fitting recording** is analysed on its
own (:func:`ssamb.closeloop.analyse`: calibration, effects, joint refit, with its own split); then

1. **agreement**: a parameter identified in several recordings must agree between them. For two
   estimates :math:`(p_a, s_a)`, :math:`(p_b, s_b)` the disagreement is
   :math:`z_{ab} = (p_a - p_b)/\sqrt{s_a^2 + s_b^2}`; the parameter agrees when every pair has
   :math:`|z_{ab}| \le` ``max_z`` (3);
2. **combined model**: one calibration of the shared parameters on all fitting recordings at once
   (:func:`joint_calibration`: every combination of parameters any recording determines, each
   recording with its own session parameters), every shared parameter at its estimate, identified
   or not; without the recordings' data, each parameter is the inverse-variance weighted mean of
   its identified estimates, :math:`\bar p = \sum w_k p_k / \sum w_k`, :math:`w_k = s_k^{-2}`, with the
   standard error :math:`(\sum w_k)^{-1/2}` times the Birge ratio :math:`\max(1, \sqrt{\chi^2/(K-1)})`,
   :math:`\chi^2 = \sum w_k (p_k - \bar p)^2` (estimates that scatter beyond their errors widen
   it); an effect found in any fitting recording enters with its parameters combined that way;
3. **held-out recordings**: the published-parameter (nominal) model and the combined model are
   replayed on every held-out recording (the mean of ``replay_seeds`` replays). Per channel, the
   rms error over the analysed part of the usable stretch, and the channel's noise floor: the rms
   spread of the final model's single replays about their mean, times :math:`\sqrt{1 + 1/m}` (the
   recording is one more realisation of the loop's noise, the prediction the mean of :math:`m`),
   bounded in every frequency band by the measured residual (:func:`noise_floor`: a model noisier
   than the rig does not raise the floor). A channel is above its floor when the nominal model's
   error exceeds twice it;
4. **held-out test of each effect**: the combined model with and without it, on the whitened
   features of each held-out recording's two parts (:func:`ssamb.closeloop.fit.holdout_score`'s
   statistic :math:`z`), combined over the :math:`K` parts as :math:`\sum z_k/\sqrt K`; an
   effect stays in the findings only when this exceeds :math:`z_{1-\alpha}` (``alpha_accept``). An
   effect found in single recordings with which every start of the joint calibration drops the body
   on a fitting recording is contradicted by them: the combined model is calibrated without it,
   and it is listed among ``effects_rejected`` with the reason (``contradicted``).

The result has the top-level keys of a single recording's ``closeloop.json`` (``effects``,
``unexplained``, ``error_before``/``error_after`` per channel, on the held-out recordings,
``parameters``, ``not_identifiable``) and adds ``recordings`` (each fitting recording's findings),
``agreement``, ``calibration_agreement`` (every calibrated parameter across the fitting recordings,
identified or not: :func:`calibration_agreement`), ``holdout`` (per held-out recording and channel)
and ``effects_rejected``.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np
from scipy import stats

__all__ = ["combine_estimates", "combine_parameters", "combine_effects", "calibration_agreement",
           "joint_calibration", "analyse_recordings", "run_recordings", "data_key", "in_data_order"]


def combine_estimates(values, ses, max_z: float = 3.0) -> dict:
    """Inverse-variance weighted mean of independent estimates and their pairwise agreement
    (module docstring, steps 1-2).

    Returns ``{value, se, birge, max_pair_z, agree, n}``.

    Examples
    --------
    >>> d = combine_estimates([1.0, 1.2], [0.1, 0.1])
    >>> round(d["value"], 6), round(d["max_pair_z"], 4), d["agree"]
    (1.1, 1.4142, True)
    """
    v = np.asarray(values, float)
    s = np.asarray(ses, float)
    w = 1.0 / np.maximum(s, 1e-300) ** 2
    m = float(np.sum(w * v) / np.sum(w))
    se = float(1.0 / math.sqrt(np.sum(w)))
    k = len(v)
    chi2 = float(np.sum(w * (v - m) ** 2))
    birge = math.sqrt(chi2 / (k - 1)) if k > 1 else 1.0
    zmax = 0.0
    for a in range(k):
        for b in range(a + 1, k):
            zmax = max(zmax, float(abs(v[a] - v[b]) / math.hypot(s[a], s[b])))
    return {"value": m, "se": se * max(1.0, birge), "birge": birge, "max_pair_z": zmax,
            "agree": bool(zmax <= max_z), "n": k}


def combine_parameters(reports: Mapping[str, dict], max_z: float = 3.0,
                       session: tuple = ()) -> tuple[dict, dict, dict]:
    """The calibrated parameters of several recordings' ``closeloop.json``: combined values,
    agreement, and the parameters no recording identified (with each recording's reason).

    Returns ``(parameters, agreement, not_identifiable)``: ``parameters`` in the format of
    ``closeloop.json`` (``value``, ``se``, ``nominal``, ``relative_change``, ``identifiable``) plus
    ``per_recording``; ``agreement`` per parameter identified in two or more recordings. The
    ``session`` parameters (:attr:`Settings.session`) are left out of all three.
    """
    keys = list(dict.fromkeys(k for r in reports.values() for k in r.get("parameters", {}) if k not in session))
    params, agree = {}, {}
    for key in keys:
        per = {n: r["parameters"][key] for n, r in reports.items() if key in r.get("parameters", {})}
        c = combine_estimates([p["value"] for p in per.values()], [p["se"] for p in per.values()], max_z)
        nominal = next(iter(per.values()))["nominal"]
        params[key] = {"value": c["value"], "se": c["se"], "nominal": nominal,
                       "relative_change": c["value"] / nominal - 1.0 if nominal else None,
                       "change": c["value"] - nominal, "identifiable": True,
                       "per_recording": {n: {"value": p["value"], "se": p["se"]} for n, p in per.items()}}
        if len(per) > 1:
            agree[key] = {"max_pair_z": c["max_pair_z"], "agree": c["agree"], "birge": c["birge"],
                          "recordings": list(per)}
    not_ident = {}
    for n, r in reports.items():
        for key, why in r.get("not_identifiable", {}).items():
            if key not in params and key not in session:
                not_ident.setdefault(key, {})[n] = why
    return params, agree, {k: "; ".join(f"{n}: {w}" for n, w in v.items()) for k, v in not_ident.items()}


def calibration_agreement(reports: Mapping[str, dict], session: tuple = ()) -> dict:
    r"""Whether every calibrated parameter, identified or not, agrees across the recordings.

    Per parameter, from each recording's ``calibration`` block (its estimate :math:`p_k` and
    standard error :math:`s_k`, whatever the data identified): the inverse-variance weighted mean
    :math:`\bar p` and :math:`\chi^2 = \sum_k (p_k - \bar p)^2 / s_k^2` on :math:`K - 1` degrees
    of freedom with its p-value (small: the recordings disagree beyond their errors), and per
    recording whether the data identified it and whether its calibration stopped short. A
    parameter no recording identified agrees trivially (its errors are the prior's): the count of
    recordings that identified it says how much the agreement means. The ``session`` parameters
    (re-zeroed per recording) are left out.

    Returns ``{key: {value, chi2, dof, p, identified_in, per_recording}}`` for the parameters
    calibrated in two or more recordings.
    """
    per: dict = {}
    for n, r in reports.items():
        cal = r.get("calibration") or {}
        for q in cal.get("parameters", []):
            if q["key"] in session or not (q["se"] > 0 and math.isfinite(q["se"])):
                continue
            per.setdefault(q["key"], {})[n] = {"value": q["value"], "se": q["se"], "identified": q["identified"],
                                              "stopped_short": bool(cal.get("stopped_short", False))}
    out = {}
    for key, d in per.items():
        if len(d) < 2:
            continue
        v = np.array([x["value"] for x in d.values()])
        w = 1.0 / np.array([x["se"] for x in d.values()]) ** 2
        m = float(np.sum(w * v) / np.sum(w))
        chi2 = float(np.sum(w * (v - m) ** 2))
        out[key] = {"value": m, "chi2": chi2, "dof": len(d) - 1, "p": float(stats.chi2.sf(chi2, len(d) - 1)),
                    "identified_in": [n for n, x in d.items() if x["identified"]], "per_recording": d}
    return out


def _effect_key(spec: Mapping) -> tuple:
    """Effects are the same when their name and their non-numeric parameters (an axis) agree."""
    return (spec["name"],) + tuple(sorted((k, v) for k, v in spec.items() if k != "name" and isinstance(v, str)))


def combine_effects(reports: Mapping[str, dict]) -> list[dict]:
    """The effects found in the recordings, each once, with its numeric parameters combined over
    the recordings that found it (weighted by their uncertainty where the report gives one).

    Returns a list of ``{spec, found_in, uncertainty}`` (``spec``: the effect as the replay takes it).
    """
    groups: dict = {}
    for n, r in reports.items():
        unc = {}
        for e in r.get("effects", []):
            unc[_effect_key({"name": e["name"], **e["params"]})] = e.get("uncertainty", {})
        for spec in r.get("final_model", {}).get("effects", []):
            groups.setdefault(_effect_key(spec), []).append((n, spec, unc.get(_effect_key(spec), {})))
    out = []
    for key, items in groups.items():
        spec = dict(items[0][1])
        uncertainty = {}
        for p, v in items[0][1].items():
            if p == "name" or isinstance(v, str):
                continue
            vals = [float(s[p]) for _, s, _ in items]
            ses = [float(u.get(p, 0.0)) or abs(val) * 1e-3 + 1e-300 for (_, _, u), val in zip(items, vals)]
            c = combine_estimates(vals, ses)
            spec[p] = c["value"]
            uncertainty[p] = c["se"]
        out.append({"spec": spec, "found_in": [n for n, _, _ in items], "uncertainty": uncertainty})
    return out


def _analysed_range(rec, settings) -> slice:
    """The samples of a held-out recording that are judged: its longest usable stretch after the
    start-up the analysis discards."""
    from .data import usable_range

    a, b = usable_range(rec)
    return slice(max(a, int(math.ceil(settings.discard_s * rec.fs_hz))), b)


def _band_powers(x: np.ndarray, nper: int, n_bands: int) -> np.ndarray:
    """Welch power of ``x`` (rows: realisations, averaged) summed in ``n_bands`` logarithmically spaced
    bands of the one-sided spectrum above DC (the lowest band starts at the first bin)."""
    from scipy import signal

    _, P = signal.welch(np.atleast_2d(x), nperseg=nper, detrend="constant", axis=-1)
    P = np.mean(P, axis=0)[1:]
    edges = np.unique(np.round(np.geomspace(1, len(P) + 1, n_bands + 1)).astype(int)) - 1
    return np.array([P[a:b].sum() for a, b in zip(edges[:-1], edges[1:])])


def noise_floor(meas: np.ndarray, final: np.ndarray, runs: list, n_bands: int = 8) -> dict:
    r"""The noise floor of one channel's held-out error (module docstring, step 3).

    The replays of the final model are realisations of its noise; their spread about their mean,
    :math:`\sigma_r` per sample, times :math:`\sqrt{1 + 1/m}`, is the rms error a model that is
    right would leave (the recording one more realisation). That holds only where the model's
    noise *is* the rig's: a model whose loop is less damped than the rig's, or whose replays
    diverge, spreads more than the rig's noise does, and its spread would hide its own failure.
    The data bound it: the measured residual about the final model's prediction holds the rig's
    noise plus any misfit, so in no frequency band can the rig's noise exceed it. Per band
    :math:`b` (Welch, logarithmically spaced) with the replays' spread power :math:`S_b` (about
    their mean, times :math:`m/(m-1)` and :math:`1 + 1/m`) and the residual's :math:`R_b`:

    .. math:: \text{floor}^2 = \sigma_r^2 (1 + 1/m) \frac{\sum_b \min(S_b, R_b)}{\sum_b S_b}

    Returns
    -------
    dict
        ``rms`` (the floor), ``replays_rms`` (the spread alone, :math:`\sigma_r\sqrt{1+1/m}`) and
        ``capped_bands`` (the bands' upper frequencies as fractions of Nyquist where the spread
        exceeds the residual).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> runs = [rng.standard_normal(4096) for _ in range(8)]
    >>> d = noise_floor(rng.standard_normal(4096), np.mean(runs, axis=0), runs)
    >>> 0.9 < d["rms"] / d["replays_rms"] <= 1.0
    True
    >>> d = noise_floor(0.1 * rng.standard_normal(4096), np.zeros(4096), runs)
    >>> round(d["rms"], 1)
    0.1
    """
    m = len(runs)
    y = np.asarray(meas, float)
    if m < 2:
        return {"rms": 0.0, "replays_rms": 0.0, "capped_bands": []}
    R = np.asarray(runs, float)
    mean = R.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.var(R, axis=0, ddof=1))) * math.sqrt(1.0 + 1.0 / m))
    n = y.size
    nper = int(min(256, 2 ** int(math.floor(math.log2(max(n // 4, 16))))))
    if n < 2 * nper or spread == 0.0:
        return {"rms": spread, "replays_rms": spread, "capped_bands": []}
    S = _band_powers(R - mean, nper, n_bands) * (m / (m - 1.0)) * (1.0 + 1.0 / m)
    Rb = _band_powers(y - np.asarray(final, float), nper, n_bands)
    keep = np.minimum(S, Rb)
    frac = float(keep.sum() / S.sum()) if S.sum() > 0 else 1.0
    edges = np.unique(np.round(np.geomspace(1, nper // 2 + 1, n_bands + 1)).astype(int))
    capped = [float(edges[j + 1] / (nper // 2 + 1)) for j in range(len(S)) if Rb[j] < S[j]]
    return {"rms": spread * math.sqrt(frac), "replays_rms": spread, "capped_bands": capped}


def _channel_errors(dev, rec, sl: slice, nominal: dict, final: dict, runs: list) -> dict:
    """Per channel: rms error of both models over ``sl``, the noise floor (:func:`noise_floor`) and
    whether the nominal model's error stands above twice it."""
    out = {}
    for c in dev.channels:
        y = rec.channels[c][sl]
        fl = noise_floor(y, final[c][sl], [r[c][sl] for r in runs])
        floor = fl["rms"]
        before = float(np.sqrt(np.mean((y - nominal[c][sl]) ** 2)))
        after = float(np.sqrt(np.mean((y - final[c][sl]) ** 2)))
        out[c] = {"rms_before": before, "rms_after": after, "noise_rms": floor,
                  "noise_rms_replays": fl["replays_rms"],
                  "above_noise": bool(before > 2 * floor), "ratio": after / before if before > 0 else float("nan"),
                  "samples": int(y.size)}
    return out


def _holdout_z(dev, name: str, arrays, meta, cfg, settings, overrides: dict, with_eff: list, without_eff: list,
               workers: int) -> list[float]:
    """Held-out statistic ``z`` of the model with an effect against the model without it, on the
    two parts of one held-out recording (:func:`ssamb.closeloop.fit.holdout_score`'s form)."""
    from .comparison import Comparison
    from .data import make_split
    from .fit import Base, improvement_z
    from .replay import Replayer

    rec = dev.record(arrays, meta, cfg, name)
    split = make_split(rec, settings.fit_fraction, settings.discard_s, settings.min_fit_s, settings.min_holdout_s, name)
    replay = Replayer(cfg, rec, workers=workers)
    try:
        cmp = Comparison.build(rec, split, replay, range(1, settings.replay_seeds + 1), settings)
        cmp.calibrate_noise(overrides, without_eff)
        base = Base(overrides, without_eff, cmp.prediction(overrides, without_eff))
        pred = cmp.prediction(overrides, with_eff)
        out = []
        for part in (cmp.fit, cmp.hold):
            out.append(improvement_z(cmp, part, base, pred, overrides, with_eff))
        return out
    finally:
        replay.close()


_CONTRADICTED = ("with the effects found in single fitting recordings in the model, every start of the joint "
                 "calibration drops the body on a fitting recording: the combined model is calibrated without them")

_SESSION_ERRORS_ON = ", after each one's own fitting part, on which its session parameters are calibrated"


def _session_fit(dev, name: str, rec, cfg, overrides: dict, effects: list, settings, workers: int,
                 starts: list = ()) -> tuple:
    """The session parameters of one held-out recording, calibrated on its own fitting part with
    everything else at ``overrides`` (the combined model), from the device's start for them or
    one of ``starts`` (session overrides, e.g. the fitting recordings' own): ``(session overrides,
    the part's slice to judge, their estimates)``."""
    from ..config import apply_overrides
    from .calibration import bounded, calibrate_model, findings, overrides_of, parameter_specs
    from .comparison import Comparison
    from .data import make_split
    from .estimate import EstimateSettings, drops_and_cost
    from .replay import Replayer

    split = make_split(rec, settings.fit_fraction, settings.discard_s, settings.min_fit_s, settings.min_holdout_s, name)
    base = apply_overrides(cfg, overrides) if overrides else cfg
    specs = bounded(parameter_specs(base, {k: v for k, v in settings.calibration.items() if k in settings.session}),
                    dev.calibration_bounds(rec, base))
    replay = Replayer(base, rec, workers=workers)
    try:
        cmp = Comparison.build(rec, split, replay, range(1, settings.replay_seeds + 1), settings)
        init = dev.initial_estimate(cmp.record, base)
        cands = [{k: v for k, v in init.items() if k in settings.session}] + [dict(c) for c in starts]
        est = EstimateSettings(**settings.estimate)
        # the noise read about the data's own start; the calibration starts from the candidate (that
        # start, or a fitting recording's session values) whose replays drop the body least and fit
        # the recording's first part best, and reads the noise about it
        cmp.calibrate_noise(cands[0] or None, effects)
        ev = cmp.evaluator(cmp.fit, lambda th: (overrides_of(specs, th), list(effects)))
        thetas = [np.clip([sp.theta_of(c[sp.key]) if sp.key in c else 0.0 for sp in specs],
                          [-np.inf if sp.lower is None else sp.theta_of(sp.lower) for sp in specs],
                          [np.inf if sp.upper is None else sp.theta_of(sp.upper) for sp in specs]) for c in cands]
        score = [drops_and_cost([ev(th, 650_500 + j) for j in range(est.centre_runs)]) for th in thetas]
        start = thetas[min(range(len(thetas)), key=lambda j: score[j])]
        cmp.calibrate_noise(overrides_of(specs, start), effects)
        cal = calibrate_model(cmp, specs, effects, EstimateSettings(**settings.estimate), settings.identifiable_ratio,
                              settings.conflict_z, start=start, restarts=settings.calibration_restarts)
    finally:
        replay.close()
    found, _ = findings(specs, cal.theta, cal.ident)
    ov = {sp.key: sp.value(float(t)) for sp, t in zip(specs, cal.theta)}
    return ov, split.hold, {k: {"value": ov[k], "se": found[k]["se"] if k in found else None,
                                "identified": k in found} for k in ov}


def _joint_problem(cmps: list, shared: list, sess: list, effects: list, seed0: int = 700_000, names=None):
    r"""The :class:`~ssamb.closeloop.estimate.Problem` of one calibration over several recordings
    (:func:`joint_calibration`): the parameter vector is the shared parameters, then each
    recording's own session parameters (``sess``: per recording, the specs of its session
    parameters, whose data-implied limits differ; named ``recording:key`` with the recordings'
    ``names``, default their positions); the residual is the recordings' whitened residuals end to
    end (each part's noise groups kept), infeasible when any recording's replay is."""
    from .calibration import calibration_problem, overrides_of
    from .estimate import Problem

    ns, nk = len(shared), len(sess[0]) if sess else 0
    parts = [calibration_problem(shared, None)] + [calibration_problem(sp, None) for sp in sess]

    def build(k):
        def b(theta):
            ov = overrides_of(shared, theta[:ns])
            ov.update(overrides_of(sess[k], theta[ns + k * nk: ns + (k + 1) * nk]))
            return ov, list(effects)
        return b
    evals = [c.evaluator(c.fit, build(k)) for k, c in enumerate(cmps)]
    manys = [c.evaluate_many(c.fit, build(k)) for k, c in enumerate(cmps)]
    groups, off = [], 0
    for c in cmps:
        g = c.groups(c.fit)
        groups += [np.asarray(x) + off for x in g]
        off += len(c.fit.whitener.residual(c.fit.data, c.fit.data))

    def evaluate(theta, seed):
        return np.concatenate([np.asarray(e(theta, seed), float) for e in evals])

    def evaluate_many(tasks):
        res = [m(tasks) for m in manys]
        return [np.concatenate([np.asarray(r[j], float) for r in res]) for j in range(len(tasks))]
    cat = lambda a: np.concatenate([getattr(p, a) for p in parts])  # noqa: E731
    labels = list(names) if names is not None else [str(k) for k in range(len(sess))]
    return Problem(names=tuple(s.key for s in shared) + tuple(f"{labels[k]}:{sp.key}" for k, sp_k in enumerate(sess)
                                                           for sp in sp_k),
                   theta0=cat("theta0"), prior_sd=cat("prior_sd"),
                   step=cat("step"), lower=cat("lower"), upper=cat("upper"), evaluate=evaluate,
                   seed0=seed0, groups=groups, evaluate_many=evaluate_many), build


def _session_start(cmp, shared: list, sess: list, theta_shared, phi0, effects: list, est,
                   others: tuple = ()) -> np.ndarray:
    """A recording's session parameters (:attr:`Settings.session`) calibrated on its fitting part
    with the shared parameters held at ``theta_shared`` (a start for :func:`joint_calibration`),
    from ``phi0`` or one of ``others`` (e.g. those of the recording whose shared
    parameters these are: the same rig, re-zeroed), whichever of them drops the body least and
    fits the part best (:func:`ssamb.closeloop.estimate.drops_and_cost`; only ``phi0`` when there
    are no others); the device's own start for them when that one is infeasible there."""
    import dataclasses

    from .calibration import calibration_problem, overrides_of
    from .estimate import drops_and_cost, map_fit

    if not sess:
        return np.zeros(0)
    fixed = overrides_of(shared, theta_shared)

    def build(phi):
        return {**fixed, **overrides_of(sess, phi)}, list(effects)
    init = cmp.device.initial_estimate(cmp.record, cmp.replay.cfg)
    prob = calibration_problem(sess, None, seed0=650_000, start=np.asarray(phi0, float))
    prob.fallback = np.array([sp.theta_of(init[sp.key]) if sp.key in init else 0.0 for sp in sess])
    prob.evaluate, prob.evaluate_many = cmp.evaluator(cmp.fit, build), cmp.evaluate_many(cmp.fit, build)
    if others:
        starts = [np.clip(np.asarray(p, float), prob.lower, prob.upper) for p in (phi0, *others)]
        score = [drops_and_cost(prob.batch([(th, 650_500 + j) for j in range(est.centre_runs)])) for th in starts]
        prob.start = starts[min(range(len(starts)), key=lambda j: score[j])]
    return map_fit(prob, dataclasses.replace(est, max_iter=4, short_iter=0)).theta


def joint_calibration(dev, fit: Mapping, reps: Mapping, cfg, settings, effects: list, workers: int = 1,
                      progress: bool = False) -> dict | None:
    r"""One calibration of the parameters the fitting recordings share, on all of them at once.

    Each recording's own calibration (:func:`ssamb.closeloop.analyse`) determines a few
    combinations of the parameters and leaves the others to its prior; which combinations
    depends on what its excitation moves (a constant reference reads the force balance at one
    gap, steps read it at several and the loop's dynamics with it). Kept one by one, only a
    parameter that a single recording pins down would reach the combined model -- often none,
    and then the combined model is the published one however well each recording's calibrated
    model predicts. The maximum a posteriori of all fitting data together,

    .. math:: \hat\theta = \arg\min_{\theta, \phi_1..\phi_K} \sum_k \|r_k(\theta, \phi_k)\|^2
              + \|\theta/\sigma_\theta\|^2 + \sum_k \|\phi_k/\sigma_\phi\|^2,

    with the shared parameters :math:`\theta` and each recording's session parameters
    :math:`\phi_k` (:attr:`Settings.session`: a sensor re-zeroed between recordings), holds every
    combination any recording determines. Each recording's residual :math:`r_k` is its fitting
    part's whitened features (:class:`~ssamb.closeloop.comparison.Comparison`), its whitener
    built at that recording's own calibrated model (the noise of the replays about a model that
    levitates like the rig, not about one that may drop the body). The estimator is
    :func:`ssamb.closeloop.estimate.map_fit`; it starts from the recordings' calibrated values of
    :math:`\theta` (each with every recording's own :math:`\phi_k`) whose mean replays give the
    lowest summed cost, since the cost is not convex and a start near one recording's optimum may
    drop the body on another. The recordings' found effects stay in the model as combined.

    Returns
    -------
    dict or None
        ``overrides`` (every shared parameter at its estimate: the combined model), ``parameters``
        and ``not_identifiable`` (``closeloop.json`` format, the identified ones with each
        recording's own calibrated value), ``session`` (recording -> its session overrides) and
        ``block`` (the fit's summary: start, costs, convergence, identifiability); None without
        a fitting recording's data or without a shared parameter.
    """
    from .calibration import bounded, findings, identifiability, parameter_specs
    from .comparison import Comparison
    from .data import make_split
    from .estimate import EstimateSettings, best_fit, drops_and_cost
    from .replay import Replayer
    from .search import _log

    session = tuple(settings.session)
    cal = settings.calibration or {}
    shared = parameter_specs(cfg, {k: v for k, v in cal.items() if k not in session})
    sess0 = parameter_specs(cfg, {k: cal[k] for k in session})
    names = [n for n in reps if n in fit]
    if not shared or not names:
        return None
    sess = []
    seeds = range(1, settings.replay_seeds + 1)
    cmps, replays = [], []
    try:
        for n in names:
            arrays, meta = fit[n]
            rec = dev.record(arrays, meta, cfg, n)
            lim = dev.calibration_bounds(rec, cfg)
            shared = bounded(shared, lim)          # every recording's limits on a shared parameter
            sess.append(bounded(sess0, lim))
            split = make_split(rec, settings.fit_fraction, settings.discard_s, settings.min_fit_s,
                               settings.min_holdout_s, n)
            rp = Replayer(cfg, rec, workers=workers)
            replays.append(rp)
            c = Comparison.build(rec, split, rp, seeds, settings)
            c.stops_infeasible = not dev.measured_contact(rec, cfg, settings)
            own = reps[n].get("final_model") or {}
            c.calibrate_noise(own.get("overrides") or None, own.get("effects") or [])
            cmps.append(c)
        prob, _ = _joint_problem(cmps, shared, sess, effects, names=names)
        ns, nk = len(shared), len(sess0)
        own_theta = []
        for n in names:
            ov = (reps[n].get("final_model") or {}).get("overrides") or {}
            own_theta.append(np.array([sp.theta_of(ov[sp.key]) if sp.key in ov else 0.0 for sp in shared + sess0]))
        candidates, costs, dropped = [], [], []
        est = EstimateSettings(**settings.estimate)
        for j, t in enumerate(own_theta):
            # the other recordings re-zeroed under this recording's shared parameters (their own
            # session parameters belong to their own calibrations of the shared ones: from them, or
            # from this recording's, whichever fits better there)
            phis = [t[ns:] if k == j else _session_start(c, shared, sess[k], t[:ns], own_theta[k][ns:], effects, est,
                                                         (t[ns:],))
                    for k, c in enumerate(cmps)]
            th = np.clip(np.concatenate([t[:ns]] + phis), prob.lower, prob.upper)
            drops, cost = drops_and_cost(prob.batch([(th, 600_000 + 500 + s) for s in range(est.centre_runs)]))
            candidates.append(th)
            costs.append(cost)
            dropped.append(drops)
            _log(progress, f"joint calibration: start at {names[j]}'s calibration: cost {cost:.4g} "
                           f"({drops} of {est.centre_runs} replays infeasible)")
        best = min(range(len(costs)), key=lambda j: (dropped[j], costs[j]))
        prob.start = candidates[best] if np.isfinite(costs[best]) else None
        fit_, restarts = best_fit(prob, est, settings.calibration_restarts,
                                  (lambda m: _log(progress, "  joint calibration " + m)) if progress else None)
    finally:
        for rp in replays:
            rp.close()
    sd = np.asarray(prob.prior_sd, float)
    all_names = prob.names
    rel = tuple(sp.relative for sp in shared) + tuple(sp.relative for _ in names for sp in sess0)
    ident = identifiability(fit_.info, sd, all_names, settings.identifiable_ratio, cov=fit_.cov_misfit,
                            cov_noise=fit_.cov, relative=rel)
    params, not_ident = findings(shared, fit_.theta[:ns], ident)
    for key, p in params.items():
        p["per_recording"] = {n: {"value": q["value"], "se": q["se"], "identified": q["identified"]}
                              for n in names for q in (reps[n].get("calibration") or {}).get("parameters", [])
                              if q["key"] == key}
    ov = {sp.key: sp.value(float(t)) for sp, t in zip(shared, fit_.theta[:ns])}
    sess_ov = {n: {sp.key: sp.value(float(fit_.theta[ns + k * nk + i])) for i, sp in enumerate(sess0)}
               for k, n in enumerate(names)}
    per = []
    for i, sp in enumerate(shared):
        d = ident["per_parameter"][sp.key]
        scale = abs(sp.nominal) if sp.relative else 1.0
        per.append({"key": sp.key, "nominal": sp.nominal, "value": ov[sp.key], "se": d["se"] * scale,
                    "tolerance": sp.prior_sd * scale, "identified": d["identified"], "reason": d["reason"]})
    block = {"recordings": names, "start": names[best] if np.isfinite(costs[best]) else "nominal",
             "start_costs": dict(zip(names, costs)), "parameters": per, "rank": ident["rank"],
             "combinations": ident["combinations"], "converged": bool(fit_.converged),
             "stopped_short": bool(fit_.stopped_short), "cost": fit_.chi2, "n": fit_.n,
             "cost_over_noise_floor": fit_.chi2 / fit_.floor if fit_.floor > 0 else None,
             "simulations": int(fit_.evaluations) * len(names), "infeasible_replays": int(fit_.infeasible)}
    if restarts:
        block["restarts"] = restarts
    return {"overrides": ov, "parameters": params, "not_identifiable": not_ident, "session": sess_ov,
            "block": block}


def analyse_recordings(fit: Mapping[str, tuple], hold: Mapping[str, tuple], cfg: Mapping, device="amb",
                       workers: int = 1, progress: bool = False, reports: Mapping[str, dict] | None = None) -> dict:
    """Calibrate on the fitting recordings, judge on the held-out ones (module docstring).

    Parameters
    ----------
    fit, hold : mapping
        ``name -> (arrays, meta)`` of the fitting and the held-out recordings (the device's data
        format; ``fit`` may be empty when ``reports`` holds their analyses).
    cfg : mapping
        The device's configuration (its ``closeloop`` section sets the analysis).
    device : str or ssamb.device.Device
    workers : int
        Processes for the independent replays.
    progress : bool
    reports : mapping, optional
        ``name -> closeloop.json`` of fitting recordings already analysed (a workflow's earlier
        jobs); recordings named in both are not analysed again.

    Returns
    -------
    dict
        The combined ``closeloop.json``.
    """
    return _analyse_recordings(fit, hold, cfg, device, workers, progress, reports)[0]


def data_key(dev, arrays: Mapping) -> str:
    """A recording's place in the order the recordings are processed in: the SHA-256 of its
    logged channels (:attr:`ssamb.device.Device.channels`, float64), which its name or its
    position on a command line do not change."""
    import hashlib

    h = hashlib.sha256()
    for c in dev.channels:
        h.update(c.encode())
        h.update(np.ascontiguousarray(np.asarray(arrays[c], dtype=np.float64)).tobytes())
    return h.hexdigest()


def in_data_order(dev, recordings: Mapping) -> dict:
    r"""``recordings`` (name -> ``(arrays, meta)``) in the order their data define (:func:`data_key`).

    The recordings given are a set. The joint calibration's parameter vector lists each
    recording's session parameters in turn, and the estimator's design gives each position its
    own perturbation pattern (:func:`ssamb.closeloop.estimate._pairs`); sums over recordings
    (pooled errors, weighted means) round differently in another order. Processed in an order
    the data define, the same files give the same numbers however they are named or listed (a
    command line, a workflow whose config is sorted by name).
    """
    return dict(sorted(recordings.items(), key=lambda kv: data_key(dev, kv[1][0])))


def _report_key(rep: Mapping) -> str:
    """The order of a fitting recording known only by its analysis (no data given): a hash of
    its final model and calibration, which its name does not change."""
    from ..config import config_hash

    return config_hash({k: rep.get(k) for k in ("final_model", "calibration")})


def _analyse_recordings(fit, hold, cfg, device, workers, progress, reports):
    from ..device import get_device
    from . import _analyse
    from .replay import Replayer
    from .settings import settings_from_config

    dev = get_device(device)
    settings = settings_from_config(cfg, dev)
    fit, hold = in_data_order(dev, fit), in_data_order(dev, hold)
    given = dict(reports or {})
    reps = {}
    for name, (arrays, meta) in fit.items():
        reps[name] = given[name] if name in given else \
            _analyse(arrays, meta, cfg, source=name, progress=progress, workers=workers, device=dev)[0]
    reps.update(sorted(((n, r) for n, r in given.items() if n not in fit), key=lambda x: _report_key(x[1])))
    session = tuple(settings.session)
    params, agree, not_ident = combine_parameters(reps, session=session)
    found = combine_effects(reps)
    overrides = {k: p["value"] for k, p in params.items()}
    effects = [f["spec"] for f in found]
    sessions = {k: {"fit": {n: r["parameters"][k] for n, r in reps.items() if k in r.get("parameters", {})},
                    "hold": {}} for k in session}
    joint = joint_calibration(dev, fit, reps, cfg, settings, effects, workers, progress)
    contradicted = []
    if joint is not None and effects and joint["block"]["start"] == "nominal":
        # with the effects found in single recordings every start drops the body on a fitting
        # recording (and the published model does): those recordings contradict them
        retry = joint_calibration(dev, fit, reps, cfg, settings, [], workers, progress)
        if retry is not None and retry["block"]["start"] != "nominal":
            contradicted, found, effects, joint = found, [], [], retry
    if joint is not None:                 # the combined model: every shared parameter, from all fitting data
        overrides = dict(joint["overrides"])
        params, not_ident = joint["parameters"], joint["not_identifiable"]
        for k in session:
            sessions[k]["fit_joint"] = {n: ov[k] for n, ov in joint["session"].items()}
    seeds = list(range(1, settings.replay_seeds + 1))
    holdout, ev_z, contact, art = {}, {i: [] for i in range(len(found))}, {}, []
    pooled = {c: {"before": [], "after": [], "noise": []} for c in dev.channels}
    for name, (arrays, meta) in hold.items():
        dev.validate(arrays, name)
        rec = dev.record(arrays, meta, cfg, name)
        sl = _analysed_range(rec, settings)
        ov = dict(overrides)
        if session:                       # re-zeroed on the recording's own first part, judged on the rest
            sov, sl, est = _session_fit(dev, name, rec, cfg, overrides, effects, settings, workers,
                                        list(joint["session"].values()) if joint is not None else [])
            ov.update(sov)
            for k, e in est.items():
                sessions[k]["hold"][name] = e
        replay = Replayer(cfg, rec, workers=workers)
        try:
            nominal = replay.mean((), None, {}, seeds)
            runs = replay.runs(effects, None, ov, seeds)
            final = replay.mean(effects, None, ov, seeds)
        finally:
            replay.close()
        errs = _channel_errors(dev, rec, sl, nominal, final, runs)
        art.append({"name": name, "record": rec, "range": sl, "nominal": nominal, "final": final})
        holdout[name] = {"channels": errs, "analysed_s": [sl.start / rec.fs_hz, sl.stop / rec.fs_hz],
                         "usable_reason": rec.usable_reason, "final_model_contact": bool(final["delevitated"]),
                         "measured_contact": bool(dev.measured_contact(rec, cfg, settings))}
        contact[name] = holdout[name]["final_model_contact"] and not holdout[name]["measured_contact"]
        for c, d in errs.items():
            pooled[c]["before"].append((d["rms_before"] ** 2, d["samples"]))
            pooled[c]["after"].append((d["rms_after"] ** 2, d["samples"]))
            pooled[c]["noise"].append((d["noise_rms"] ** 2, d["samples"]))
        for i in range(len(found)):
            without = [e for j, e in enumerate(effects) if j != i]
            ev_z[i] += _holdout_z(dev, name, arrays, meta, cfg, settings, ov, effects, without, workers)
    from ..config import apply_overrides

    final_cfg = apply_overrides(cfg, overrides) if overrides else cfg
    checks = {}
    for name, (arrays, meta) in {**fit, **hold}.items():
        c = {"published": dev.checks(arrays, cfg), "final": dev.checks(arrays, final_cfg)}
        if c["published"] or c["final"]:
            checks[name] = c
    z_crit = float(stats.norm.isf(settings.alpha_accept))
    kept, rejected = [], []
    for i, f in enumerate(found):
        zs = ev_z[i]
        z = float(sum(zs) / math.sqrt(len(zs))) if zs else 0.0
        entry = {"name": f["spec"]["name"], "params": {k: v for k, v in f["spec"].items() if k != "name"},
                 "uncertainty": f["uncertainty"], "found_in": f["found_in"], "holdout_z": z, "holdout_parts": zs}
        (kept if z > z_crit else rejected).append(entry)
    for f in contradicted:
        rejected.append({"name": f["spec"]["name"], "params": {k: v for k, v in f["spec"].items() if k != "name"},
                         "uncertainty": f["uncertainty"], "found_in": f["found_in"], "holdout_z": None,
                         "holdout_parts": [], "contradicted": _CONTRADICTED})
    for e in kept:
        e["error_reduction"] = None
    before = {c: _pool(v["before"]) for c, v in pooled.items()}
    after = {c: _pool(v["after"]) for c, v in pooled.items()}
    noise = {c: _pool(v["noise"]) for c, v in pooled.items()}
    err_b = {c: {"rms": before[c], "noise_rms": noise[c], "above_noise": bool(before[c] > 2 * noise[c])}
             for c in dev.channels}
    err_a = {c: {"rms": after[c], "noise_rms": noise[c], "ratio_to_before": after[c] / before[c] if before[c] else None}
             for c in dev.channels}
    unexplained = any(err_a[c]["rms"] > 2 * noise[c] for c in dev.channels if err_b[c]["above_noise"])
    rep = {"effects": kept, "unexplained": bool(unexplained), "error_before": err_b, "error_after": err_a,
            "parameters": params, "not_identifiable": not_ident, "agreement": agree,
            "calibration_agreement": calibration_agreement(reps, session),
            "effects_rejected": rejected, "holdout": holdout, "stops_hit_by_model_only": contact,
            "physical_checks": checks, "effects_not_identifiable": _not_identifiable_effects(dev, hold, cfg, settings),
            "joint_calibration": joint["block"] if joint is not None else None,
            "recordings": {n: _brief(r) for n, r in reps.items()},
            "session_parameters": sessions,
            "validation": {"fit_recordings": list(reps), "holdout_recordings": list(hold),
                           "errors_on": "held-out recordings" + (_SESSION_ERRORS_ON if session else ""),
                           "alpha_accept": settings.alpha_accept},
            "data": {"device": dev.name}}
    return rep, {"device": dev, "holdout": art}


def _not_identifiable_effects(dev, recordings: Mapping, cfg, settings) -> dict:
    """The library effects the device says these recordings cannot identify, with its reason
    (:meth:`ssamb.device.Device.effect_model` returns a reason instead of a parameterisation)."""
    out = {}
    for name, (arrays, meta) in recordings.items():
        rec = dev.record(arrays, meta, cfg, name)
        for eff in dev.library:
            why = dev.effect_model(eff, {}, rec, settings)
            if isinstance(why, str):
                out.setdefault(eff, why)
    return out


def _pool(items: list) -> float:
    """rms over several recordings from their mean squares and sample counts."""
    n = sum(k for _, k in items)
    return float(math.sqrt(sum(ms * k for ms, k in items) / n)) if n else float("nan")


def _brief(rep: dict) -> dict:
    """What the combined report keeps of one recording's analysis."""
    return {k: rep.get(k) for k in ("summary", "parameters", "not_identifiable", "effects", "unexplained",
                                    "error_before", "error_after", "validation", "notes", "final_model",
                                    "calibration")}


def run_recordings(fit_paths, hold_paths, out_dir, config=None, device="amb", progress: bool = True, workers: int = 1,
                   reports: Mapping[str, str] | None = None, force: bool = False) -> dict:
    """Analyse recording files (:func:`analyse_recordings`) and write ``out_dir/closeloop.json``
    and figures (replacing ``out_dir`` whole, as :func:`ssamb.closeloop.run_closeloop` does).

    Parameters
    ----------
    fit_paths, hold_paths : sequence of path, or mapping of name -> path
        Fitting and held-out recordings, in a format of the device; a recording given as a bare
        path is named by its file's stem.
    out_dir : path
    config : path or mapping, optional
        The device's configuration (default: its own).
    device : str or ssamb.device.Device
    progress : bool
    workers : int
    reports : mapping, optional
        ``name -> closeloop.json path`` of fitting recordings analysed already.
    force : bool
        Replace a previous analysis in ``out_dir`` (:func:`ssamb.io.check_output_dir`).

    Returns
    -------
    dict
        The combined ``closeloop.json``.
    """
    import shutil
    import tempfile
    from pathlib import Path

    from ..device import get_device
    from ..errors import InputError
    from ..io import check_output_dir, read_json, replace_dir, write_json
    from .figures import make_recording_figures

    def owned(p: Path) -> bool:
        return p.is_file() and (p.name == "closeloop.json" or p.suffix == ".png")

    dev = get_device(device)
    out_dir = Path(out_dir)
    check_output_dir(out_dir, owned, force)

    def named(paths) -> list:
        return list(paths.items()) if isinstance(paths, Mapping) else [(Path(p).stem, p) for p in paths]

    fit_named, hold_named = named(fit_paths), named(hold_paths)
    names = [n for n, _ in fit_named + hold_named]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"recordings named twice (by file stem): {', '.join(dup)}")
    if not hold_named:
        raise InputError("no held-out recording: name at least one (--hold)")
    unknown = sorted(set(reports or {}) - {n for n, _ in fit_named})
    if unknown:
        raise InputError(f"analyses of recordings that are not fitting recordings: {', '.join(unknown)}")
    cfg = dict(config) if isinstance(config, Mapping) else dev.load_config(config)
    fit = {n: dev.load(p) for n, p in fit_named}
    hold = {n: dev.load(p) for n, p in hold_named}
    done = {n: read_json(p) for n, p in (reports or {}).items()}
    rep, art = _analyse_recordings(fit, hold, cfg, dev, workers, progress, done)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out_dir.parent, prefix=f".{out_dir.name}."))
    try:
        rep["figures"] = make_recording_figures(art, rep, tmp)
        write_json(tmp / "closeloop.json", rep)
        replace_dir(tmp, out_dir, owned)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rep
