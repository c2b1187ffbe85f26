r"""Stages ``ceiling`` and ``ensemble_collect``: the headline numbers as distributions over noise.

Every number the chain reports comes from simulations with converter noise in a self-sensed
loop that turns any perturbation into another noise realisation: each is one draw of a random
variable. The noise ensembles (:func:`ssamb.scenarios.ensemble_runs`) repeat a chain over
``K`` realisations (another master seed each: converter noise, excitation phases, calibration
noise); this module summarises them.

Ceiling
-------
What no model can exceed: the fit of one nonlinear run against the others, with the same
excitation and only the converter noise drawn anew (:func:`ssamb.scenarios.ceiling_runs`). The
best deterministic prediction of a channel :math:`y_j` is its conditional mean given the
excitation, estimated by the mean :math:`m_{-j}` of the other :math:`J - 1` runs. That estimate
carries the noise of :math:`J - 1` runs, which adds :math:`1/(J-1)` of a run's noise power to
the squared error; removing it,

.. math::

    \mathrm{ceiling}_j = 100\left(1 - \sqrt{\tfrac{J - 1}{J}}\,
    \frac{\|y_j - m_{-j}\|}{\|y_j - \bar y_j\|}\right),

the fit (as :func:`ssamb.identification.nrmse_fit`) that the exact conditional mean would
reach against run :math:`j` (the factor is exact when the runs' noise is independent with equal
power). Median and range over :math:`j` are reported.

Ensemble
--------
Per chain and headline quantity (:data:`QUANTITIES`): the number of realisations that have it
(``K``), the median, minimum and maximum; per yes/no outcome (:data:`OUTCOMES`) the fraction of
realisations where it holds. A quantity that needs a stable assembled loop is computed over the
stable realisations only, and the stability fraction says how many those are. Which chain
reproduces each of the paper's three headlines is computed in :func:`reproduces`.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from ..io import read_json, write_json
from ..model_io import load_record
from ..paper import PAPER
from .summary import first_failure

__all__ = ["ceiling_fits", "run_ceiling", "ceiling_channels", "QUANTITIES", "OUTCOMES", "run_quantities",
           "distribution",
           "chain_summary", "reproduces", "collect_ensemble", "ensemble_figure", "fill_shared_nonlinear", "explain"]


# ------------------------------------------------------------------------------- the ceiling
def ceiling_fits(records: Sequence[Mapping[str, np.ndarray]], channels: Sequence[str]) -> dict:
    """Ceiling of each channel over repeated runs (module docstring): per run ``j`` the fit of
    run ``j`` against the mean of the others, corrected for the noise left in that mean.

    Parameters
    ----------
    records : sequence of mapping
        At least two runs with the same excitation (columns ``channels``, equal lengths).
    channels : sequence of str

    Returns
    -------
    dict
        ``channel -> {"K", "median", "min", "max", "values"}`` (fits in percent).
    """
    J = len(records)
    if J < 2:
        raise ValueError(f"ceiling_fits: need at least 2 runs (got {J})")
    out = {}
    for c in channels:
        Y = np.stack([np.asarray(r[c], float).ravel() for r in records])
        total = Y.sum(axis=0)
        vals = []
        for j in range(J):
            others = (total - Y[j]) / (J - 1)
            den = np.linalg.norm(Y[j] - Y[j].mean())
            err = math.sqrt((J - 1) / J) * np.linalg.norm(Y[j] - others)
            vals.append(float(100.0 * (1.0 - err / den)) if den > 0 else math.nan)
        out[c] = distribution(vals)
    return out


def run_ceiling(records: Sequence[str | Path], channels: Sequence[str], out_json: str | Path) -> dict:
    """Stage ``ceiling``: :func:`ceiling_fits` of the repeated runs of one experiment (the
    default run's and those of :func:`ssamb.scenarios.ceiling_runs`), written to ``out_json``."""
    recs = []
    for p in records:
        arrays, meta = load_record(p)
        if meta.get("delevitation_s") is not None:
            raise ValueError(f"{p}: the rotor delevitated at t = {meta['delevitation_s']:.4g} s; the ceiling needs "
                             f"levitated runs")
        recs.append(arrays)
    n = {len(np.asarray(r["t"])) for r in recs}
    if len(n) != 1:
        raise ValueError(f"ceiling: the runs have different lengths {sorted(n)}")
    info = {"experiment": Path(records[0]).stem, "runs": [str(p) for p in records],
            "channels": ceiling_fits(recs, channels),
            "method": "fit of each run against the mean of the others, corrected for the noise of that mean"}
    write_json(out_json, info)
    return info


# ------------------------------------------------------------------------- the quantities
def _get(d: Any, *keys):
    for k in keys:
        if not isinstance(d, Mapping):
            return None
        d = d.get(k)
    return d


def _outcome(s: Mapping, model: str) -> Mapping:
    return next((o for o in (_get(s, "details", "validation", "outcomes") or []) if o["model"] == model), {})


def _critical_um(s: Mapping, model: str):
    a = _outcome(s, model).get("critical_amplitude_m")
    return None if a is None else a * 1e6


def _critical_augmented_um(s: Mapping):
    vals = [o.get("critical_amplitude_m") for o in (_get(s, "details", "validation", "outcomes") or [])
            if o["model"].startswith("augmented") and o.get("critical_amplitude_m") is not None]
    return min(vals) * 1e6 if vals else None


def _sub_fit(sub: str, ch: str) -> Callable:
    return lambda s: _get(s, "subsystem_fit_pct", sub, ch)


#: headline quantity -> (label, unit, extractor from a run's summary.json, ceiling: (experiment key, channel))
QUANTITIES: dict[str, tuple[str, str, Callable, tuple | None]] = {
    "fit_x_pct": ("closed-loop LTI fit, x (Fig. 4)", "%", lambda s: _get(s, "fit_pct", "x"), ("fig4", "x_meas")),
    "fit_y_pct": ("closed-loop LTI fit, y (Fig. 4)", "%", lambda s: _get(s, "fit_pct", "y"), ("fig4", "y_meas")),
    "subsystem_fit_plant_x_pct": ("plant model fit, x_meas", "%", _sub_fit("plant", "x_meas"),
                                  ("validation", "x_meas")),
    "subsystem_fit_plant_y_pct": ("plant model fit, y_meas", "%", _sub_fit("plant", "y_meas"),
                                  ("validation", "y_meas")),
    "subsystem_fit_amplifier_ypos_pct": ("amplifier model fit, i_ypos", "%", _sub_fit("amplifier", "i_ypos"),
                                         ("validation", "i_ypos")),
    "subsystem_fit_amplifier_xpos_pct": ("amplifier model fit, i_xpos", "%", _sub_fit("amplifier", "i_xpos"),
                                         ("validation", "i_xpos")),
    "subsystem_fit_selfsensing_pct": ("self-sensing model fit, y_ss", "%", _sub_fit("selfsensing", "y_ss"),
                                      ("validation", "y_ss")),
    "weight_fit_max_db": ("weight fit, largest deviation from the envelope", "dB", lambda s: s.get("weight_fit_max_db"),
                          None),
    "mu_peak": ("self-sensing μ peak", "-", lambda s: _get(s, "mu", "selfsensing", "peak"), None),
    "mu_peak_hz": ("self-sensing μ peak frequency", "Hz", lambda s: _get(s, "mu", "selfsensing", "peak_hz"), None),
    "mu_scale_for_unity": ("weight scale for a μ peak of 1 (self-sensing)", "-",
                           lambda s: _get(s, "mu", "selfsensing", "scale_for_unity"), None),
    "critical_nonlinear_um": ("critical sweep amplitude, nonlinear", "µm", lambda s: _critical_um(s, "nonlinear"),
                              None),
    "critical_nominal_um": ("critical sweep amplitude, nominal LTI", "µm", lambda s: _critical_um(s, "nominal LTI"),
                            None),
    "critical_augmented_um": ("critical sweep amplitude, augmented LTI (smallest over Δ)", "µm",
                              _critical_augmented_um, None),
    "delevitation_nonlinear_s": ("delevitation time in the sweep, nonlinear", "s",
                                 lambda s: _get(s, "delevitation_s", "nonlinear"), None),
    "delevitation_nominal_s": ("delevitation time in the sweep, nominal LTI", "s",
                               lambda s: _get(s, "delevitation_s", "nominal_lti"), None),
    "delevitation_augmented_s": ("delevitation time in the sweep, augmented LTI (earliest over Δ)", "s",
                                 lambda s: _get(s, "delevitation_s", "augmented_lti"), None),
}


def ceiling_channels(kind: str) -> list[str]:
    """Channels whose ceiling the quantities need from a ceiling kind (``fig4``: the closed-loop
    fits; ``validation``: the subsystem fits, on the identification's validation record)."""
    return list(dict.fromkeys(c[1] for *_, c in QUANTITIES.values() if c is not None and c[0] == kind))


def _delevitates(s: Mapping, model_prefix: str):
    """True/False whether a model of the sweep delevitates (None when the validation failed)."""
    outs = [o for o in (_get(s, "details", "validation", "outcomes") or []) if o["model"].startswith(model_prefix)]
    if not outs:
        return None
    return any(bool(o.get("delevitates")) for o in outs)


def _stable(s: Mapping):
    """Whether the assembled loop is stable; False when the selection by the assembled loop found
    no stable combination (then nothing was assembled); None when unknown."""
    st = _get(s, "details", "assembly", "stable")
    if st is None and "no stable assembled loop" in str((s.get("failed") or {}).get("select", "")):
        return False
    return st


#: yes/no outcome -> (label, extractor)
OUTCOMES: dict[str, tuple[str, Callable]] = {
    "stable": ("assembled LTI loop stable", _stable),
    "delevitates_nonlinear": ("nonlinear model delevitates in the sweep", lambda s: _delevitates(s, "nonlinear")),
    "delevitates_nominal": ("nominal LTI model delevitates in the sweep", lambda s: _delevitates(s, "nominal LTI")),
    "delevitates_augmented": ("an augmented LTI model delevitates in the sweep",
                              lambda s: _delevitates(s, "augmented")),
}


def run_quantities(s: Mapping) -> dict:
    """Every quantity and outcome of one run's summary (None where missing or failed)."""
    q = {k: spec[2](s) for k, spec in QUANTITIES.items()}
    q.update({k: spec[1](s) for k, spec in OUTCOMES.items()})
    nl = s.get("_shared_nonlinear")
    if nl:  # the nonlinear sweep of another run with the same simulation (fill_shared_nonlinear)
        q.update({k: v for k, v in nl.items() if q.get(k) is None})
    return q


#: quantities and outcomes of the nonlinear model alone (not of any identified model)
NONLINEAR_KEYS = ("critical_nonlinear_um", "delevitation_nonlinear_s", "delevitates_nonlinear")


def _sweep_hash(s: Mapping):
    return _get(s, "details", "simulations", "sweep", "config_hash")


def fill_shared_nonlinear(s: Mapping, others: Sequence[Mapping]) -> Mapping:
    """``s`` with the nonlinear sweep's numbers of another run whose sweep is the same
    simulation (equal config hash) under ``_shared_nonlinear``, when ``s`` lacks them (its
    validation failed on its identified models: the nonlinear model is still the same)."""
    h = _sweep_hash(s)
    q = {k: (QUANTITIES[k][2] if k in QUANTITIES else OUTCOMES[k][1])(s) for k in NONLINEAR_KEYS}
    if h is None or all(v is not None for v in q.values()):
        return s
    for o in others:
        if o is not s and _sweep_hash(o) == h:
            qo = {k: (QUANTITIES[k][2] if k in QUANTITIES else OUTCOMES[k][1])(o) for k in NONLINEAR_KEYS}
            if any(v is not None for v in qo.values()):
                return {**s, "_shared_nonlinear": qo}
    return s


def distribution(values: Sequence) -> dict:
    """``K`` (finite values), ``median``, ``min``, ``max`` and the ``values`` (None kept out)."""
    v = [float(x) for x in values if x is not None and np.isfinite(x)]
    if not v:
        return {"K": 0, "median": None, "min": None, "max": None, "values": []}
    return {"K": len(v), "median": float(np.median(v)), "min": float(min(v)), "max": float(max(v)), "values": v}


def chain_summary(runs: Sequence[str], summaries: Sequence[Mapping], ceiling: Mapping | None = None) -> dict:
    """One chain's realisations: per quantity :func:`distribution` (with the ``ceiling`` of fits
    from the ceiling stages), per outcome the ``fraction`` over the realisations where it is
    defined, the first failure of each failed realisation, and the computed causes of the μ peak."""
    qs = [run_quantities(s) for s in summaries]
    out_q = {}
    for k, (label, unit, _, ceil) in QUANTITIES.items():
        d = distribution([q[k] for q in qs])
        d.update({"label": label, "unit": unit, "runs": [r for r, q in zip(runs, qs) if q[k] is not None]})
        if ceil is not None and ceiling is not None:
            c = _get(ceiling, ceil[0], "channels", ceil[1])
            if c is not None:
                d["ceiling"] = {k2: c[k2] for k2 in ("K", "median", "min", "max")}
        out_q[k] = d
    fractions = {}
    for k, (label, _) in OUTCOMES.items():
        vals = [q[k] for q in qs if q[k] is not None]
        fractions[k] = {"label": label, "K": len(vals), "count": int(sum(bool(v) for v in vals)),
                        "fraction": (sum(bool(v) for v in vals) / len(vals)) if vals else None}
    causes: dict[str, int] = {}
    sentences = {}
    for r, s in zip(runs, summaries):
        c = _get(s, "mu", "selfsensing", "cause")
        if isinstance(c, Mapping) and c.get("cause"):
            causes[c["cause"]] = causes.get(c["cause"], 0) + 1
            sentences[r] = c.get("sentence")
    failures = {r: first_failure(s.get("failed")) for r, s in zip(runs, summaries) if s.get("failed")}
    return {"runs": list(runs), "realisations": len(runs), "quantities": out_q, "fractions": fractions,
            "failures": failures, "mu_peak_causes": causes, "mu_peak_sentences": sentences}


# ---------------------------------------------------------------- the paper's three headlines
def _inside(d: Mapping, lo: float, hi: float) -> bool:
    """Whether the ensemble's range [min, max] meets the interval [lo, hi]."""
    return d.get("K", 0) > 0 and d["min"] <= hi and d["max"] >= lo


def reproduces(chains: Mapping[str, Mapping], criteria: Mapping) -> dict:
    """Which chains reproduce each of the paper's three headlines within their ensemble spread.

    * ``fit_y``: the paper's 50.76 % inside the chain's range of the y fit (widened by
      ``criteria['fit_y_points']``);
    * ``mu_peak``: the self-sensing μ peak frequency's range meets the paper's 2 Hz within the
      factor ``criteria['mu_peak_factor']`` and the weight scale's range meets 0.0012 within
      ``criteria['mu_scale_factor']``;
    * ``delevitation``: the nonlinear model delevitates in every realisation, its time's range
      meets the paper's "just after 0.18 s" (0.18 s to 0.18 s + ``criteria['delevitation_after_s']``)
      and neither the nominal nor any augmented LTI model delevitates in any realisation.

    Returns per headline the reproducing chains and, per chain, the numbers the judgement used.
    """
    fy = float(PAPER["fit_y_pct"][0])
    f0, sc0, t0 = float(PAPER["mu_peak_hz"][0]), float(PAPER["mu_scale_for_unity"][0]), float(
        PAPER["delevitation_nonlinear_s"][0])
    tol_y, kf, ks, dt = (float(criteria[k]) for k in ("fit_y_points", "mu_peak_factor", "mu_scale_factor",
                                                     "delevitation_after_s"))
    out = {"fit_y": {"chains": [], "target": f"{fy:g} % (± {tol_y:g} points)"},
           "mu_peak": {"chains": [], "target": f"{f0:g} Hz (factor {kf:g}) with scale {sc0:g} (factor {ks:g})"},
           "delevitation": {"chains": [], "target": f"nonlinear {t0:g}-{t0 + dt:g} s in every realisation, "
                                                    "no LTI model delevitating"}}
    for name, c in chains.items():
        q, fr = c["quantities"], c["fractions"]
        if _inside(q["fit_y_pct"], fy - tol_y, fy + tol_y):
            out["fit_y"]["chains"].append(name)
        if _inside(q["mu_peak_hz"], f0 / kf, f0 * kf) and _inside(q["mu_scale_for_unity"], sc0 / ks, sc0 * ks):
            out["mu_peak"]["chains"].append(name)
        nl, nom, aug = fr["delevitates_nonlinear"], fr["delevitates_nominal"], fr["delevitates_augmented"]
        if (nl["K"] and nl["fraction"] == 1.0 and nom["K"] and nom["count"] == 0 and aug["K"] and aug["count"] == 0
                and _inside(q["delevitation_nonlinear_s"], t0, t0 + dt)):
            out["delevitation"]["chains"].append(name)
    return out


def _rng(d: Mapping, fmt: str = ".3g", unit: str = "") -> str:
    if not d.get("K"):
        return "none"
    return f"{d['median']:{fmt}}{unit} [{d['min']:{fmt}}–{d['max']:{fmt}}]"


def explain(chains: Mapping[str, Mapping], repro: Mapping, names: Mapping[str, str] | None = None) -> dict:
    """Per headline, a sentence computed from the chains' numbers: which chain reproduces it
    and, when none does, why (the ceiling, the nearest chain and its computed μ-peak cause, the
    LTI models' critical amplitudes against the sweep's)."""
    names = names or {c: c for c in chains}
    fy = float(PAPER["fit_y_pct"][0])
    out = {}
    # the y fit
    who = repro["fit_y"]["chains"]
    ceil = next((c["quantities"]["fit_y_pct"].get("ceiling") for c in chains.values()
                 if c["quantities"]["fit_y_pct"].get("ceiling")), None)
    parts = [f"Reproduced by {', '.join(names[c] for c in who)}." if who else "No chain reproduces it."]
    if ceil:
        rel = ("above every run's ceiling: no LTI model can fit the y axis that well on this simulator (its "
               "self-sensed loop's noise limits any deterministic prediction)" if fy > ceil["max"] else
               "inside the ceiling's range: the paper's fit is what an exact model reaches against one noisy run"
               if ceil["min"] <= fy <= ceil["max"] else "below the ceiling: within reach of a model")
        parts.append(f"The ceiling (nonlinear against nonlinear) is {_rng(ceil, '.4g', ' %')}; the paper's {fy:g} % "
                     f"is {rel}.")
    parts.append("The chains: " + "; ".join(f"{names[n]} {_rng(c['quantities']['fit_y_pct'], '.4g', ' %')}"
                                             for n, c in chains.items()) + ".")
    out["fit_y"] = " ".join(parts)
    # the mu peak
    who = repro["mu_peak"]["chains"]
    parts = [f"Reproduced by {', '.join(names[c] for c in who)}." if who else "No chain reproduces it."]
    for n, c in chains.items():
        q = c["quantities"]
        counts = sorted((c.get("mu_peak_causes") or {}).items(), key=lambda kv: -kv[1])
        cause = ", ".join(f"{k} in {v}" for k, v in counts)
        parts.append(f"{names[n]}: peak at {_rng(q['mu_peak_hz'], '.3g', ' Hz')}, scale "
                     f"{_rng(q['mu_scale_for_unity'], '.3g')}" + (f" (computed cause: {cause})" if cause else "") + ".")
    out["mu_peak"] = " ".join(parts)
    # the delevitation
    who = repro["delevitation"]["chains"]
    parts = [f"Reproduced by {', '.join(names[c] for c in who)}." if who else "No chain reproduces it."]
    for n, c in chains.items():
        q, fr = c["quantities"], c["fractions"]
        parts.append(f"{names[n]}: the nonlinear model delevitates in {fr['delevitates_nonlinear']['count']}/"
                     f"{fr['delevitates_nonlinear']['K']} realisations (at "
                     f"{_rng(q['delevitation_nonlinear_s'], '.3g', ' s')}; critical amplitude "
                     f"{_rng(q['critical_nonlinear_um'], '.3g', ' µm')}), the nominal LTI model in "
                     f"{fr['delevitates_nominal']['count']}/{fr['delevitates_nominal']['K']} (critical "
                     f"{_rng(q['critical_nominal_um'], '.3g', ' µm')}), an augmented one in "
                     f"{fr['delevitates_augmented']['count']}/{fr['delevitates_augmented']['K']} (critical "
                     f"{_rng(q['critical_augmented_um'], '.3g', ' µm')})." + _critical_order(q))
    out["delevitation"] = " ".join(parts)
    return out


def _critical_order(q: Mapping) -> str:
    """The paper's outcome judged by the critical amplitudes instead of one sweep amplitude: in
    how many realisations (paired by run) the nonlinear model's critical amplitude lies below both
    LTI models' (it delevitates where they hold), and the amplitudes at which that is so in every
    realisation: above the largest nonlinear and below the smallest LTI critical amplitude."""
    keys = ("critical_nonlinear_um", "critical_nominal_um", "critical_augmented_um")
    per = [dict(zip(q[k].get("runs", []), q[k].get("values", []))) for k in keys]
    runs = [r for r in per[0] if all(d.get(r) is not None for d in per)]
    if not runs:
        return ""
    below = sum(per[0][r] < min(per[1][r], per[2][r]) for r in runs)
    text = (f" The nonlinear model's critical amplitude lies below both LTI models' in {below}/{len(runs)} "
            "realisations")
    lo, hi = max(per[0][r] for r in runs), min(min(per[1][r], per[2][r]) for r in runs)
    if below == len(runs) and lo < hi:
        return text + (f": a sweep of {lo:.3g}-{hi:.3g} µm makes it delevitate while both LTI models hold in "
                       "every realisation.")
    return text + "."


# ------------------------------------------------------------------------------- the stage
def collect_ensemble(chains: Mapping[str, Sequence[tuple[str, str | Path]]], ceilings: Mapping[str, str | Path],
                     criteria: Mapping, out_json: str | Path, out_fig: str | Path | None = None) -> dict:
    """Stage ``ensemble_collect``: read every realisation's ``summary.json`` and the ceilings,
    write ``ensemble.json`` (per chain :func:`chain_summary`, its realisation 0 as
    :func:`ssamb.stages.summary.paper_way`, the ceilings, :func:`reproduces`) and the figure.

    Parameters
    ----------
    chains : mapping
        chain -> ``[(run name, summary.json), ...]`` in realisation order (0 first).
    ceilings : mapping
        ``fig4`` and ``validation`` -> the ceiling stage's JSON of that experiment.
    criteria : mapping
        config ``ensemble.criteria`` (see :func:`reproduces`).
    """
    from .summary import paper_way

    ceil = {k: read_json(p) for k, p in ceilings.items()}
    res = {"chains": {}, "ceiling": ceil, "criteria": dict(criteria)}
    every = {name: [read_json(p) for _, p in runs] for name, runs in chains.items()}
    pool = [s for sums in every.values() for s in sums]
    fig4_of = lambda s: _get(s, "details", "simulations", "fig4", "config_hash")  # noqa: E731
    default_fig4 = fig4_of(every["default"][0]) if every.get("default") else None
    for name, runs in chains.items():
        sums = [fill_shared_nonlinear(s, pool) for s in every[name]]
        # the ceilings are the default physics' runs: they bound the chains that simulate it
        same = name == "default" or (default_fig4 is not None and fig4_of(sums[0]) == default_fig4)
        c = chain_summary([r for r, _ in runs], sums, ceil if same else None)
        c["realisation_0"] = paper_way(sums[0])
        res["chains"][name] = c
    res["K"] = max((c["realisations"] for c in res["chains"].values()), default=0)
    res["reproduces"] = reproduces(res["chains"], criteria)
    for key, why in explain(res["chains"], res["reproduces"]).items():
        res["reproduces"][key]["why"] = why
    write_json(out_json, res)
    if out_fig is not None:
        ensemble_figure(res, out_fig)
    return res


#: quantities the figure shows (one panel each)
FIGURE_QUANTITIES = ("fit_y_pct", "fit_x_pct", "mu_peak_hz", "mu_scale_for_unity", "critical_nonlinear_um",
                     "critical_nominal_um", "critical_augmented_um", "delevitation_nonlinear_s")
_PAPER_KEY = {"fit_y_pct": "fit_y_pct", "fit_x_pct": "fit_x_pct", "mu_peak_hz": "mu_peak_hz",
              "mu_scale_for_unity": "mu_scale_for_unity", "delevitation_nonlinear_s": "delevitation_nonlinear_s"}


#: the lowest fit a figure panel shows (lower fits are marked at the edge)
FIT_FLOOR = -100.0


def ensemble_figure(res: Mapping, path: str | Path) -> None:
    """One panel per headline: each chain's realisations (dots), their median (bar), the ceiling's
    range for fits (grey band) and the paper's value (dashed line)."""
    import matplotlib.pyplot as plt

    from ..figures import save

    names = list(res["chains"])
    fig, axs = plt.subplots(2, 4, figsize=(15, 6.5), squeeze=False)
    for ax, key in zip(axs.ravel(), FIGURE_QUANTITIES):
        label, unit = QUANTITIES[key][:2]
        for i, n in enumerate(names):
            d = res["chains"][n]["quantities"][key]
            if d["K"]:
                ax.plot(d["values"], [i] * d["K"], "o", color=f"C{i}", alpha=0.6, ms=4)
                ax.plot([d["median"]] * 2, [i - 0.3, i + 0.3], color=f"C{i}", lw=2)
            else:
                ax.text(0.02, i, "none", transform=ax.get_yaxis_transform(), va="center", fontsize=7, color="0.4")
            c = d.get("ceiling")
            if c and c.get("K"):
                ax.fill_betweenx([i - 0.4, i + 0.4], c["min"], c["max"], color="0.8", zorder=0)
        pk = _PAPER_KEY.get(key)
        if pk is not None and PAPER[pk][0] is not None:
            ax.axvline(PAPER[pk][0], color="k", ls="--", lw=1)
        if key in ("mu_peak_hz", "mu_scale_for_unity"):
            vals = [v for n in names for v in res["chains"][n]["quantities"][key]["values"]]
            if vals and min(vals) > 0:
                ax.set_xscale("log")
        if key.endswith("_um"):  # the paper's sweep: the nonlinear model below it, the LTI models above
            ax.axvline(PAPER["sweep_amplitude_m"][0] * 1e6, color="k", ls="--", lw=1)
        if unit == "%":  # a fit far below zero would squash the others: drawn at the edge
            lo = min([v for n in names for v in res["chains"][n]["quantities"][key]["values"]] + [0.0])
            if lo < FIT_FLOOR:
                ax.set_xlim(left=FIT_FLOOR)
                for i, n in enumerate(names):
                    k = sum(v < FIT_FLOOR for v in res["chains"][n]["quantities"][key]["values"])
                    if k:
                        ax.plot([FIT_FLOOR], [i], "<", color=f"C{i}", ms=6)
                        ax.annotate(f"{k} below", (FIT_FLOOR, i + 0.15), fontsize=6, color=f"C{i}")
        ax.set_yticks(range(len(names)), names, fontsize=7)
        ax.set_ylim(-0.6, len(names) - 0.4)
        ax.set_title(f"{label} ({unit})", fontsize=8)
    fig.suptitle(f"Noise ensembles (K = {res['K']} realisations per chain): dots realisations, bar median, grey "
                 "the ceiling (nonlinear against nonlinear), dashed the paper (for the critical amplitudes: its "
                 f"{PAPER['sweep_amplitude_m'][0] * 1e6:.3g} µm sweep)", fontsize=9)
    fig.tight_layout()
    save(fig, path)
