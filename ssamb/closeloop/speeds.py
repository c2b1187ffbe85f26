r"""The speed of an effect that turns at a frequency the data measure (an unbalance's spin speed),
estimated again once the model is final, with the effect's size solved at every speed tried.

The search fits such an effect at the frequency of its line in the residual of the model without
it (the effect module's ``model``): its size parameters are fitted, its speed is not, because the
fitting part compares one phasor per line, in which a speed error and a phase error are nearly one
direction. The held-out part comes after the fitting part and sees every bit of a speed error as
a phase drift, and a size fitted at a wrong speed is wrong with it: where the line lies within
the fitting part's resolution of an excited line, the phasor of the one holds the other, and a
fraction of the resolution in speed moves the size by many of its errors at that speed.
:func:`refine_speeds` therefore estimates the speed again along the
effect's family of neighbours (``neighbours(model, theta, t_centre_s, steps)`` of the effect's
module: the speed moved in units of its standard error):

1. by the drift of the data's phase against the final model's own line over the fitting part
   (:func:`speed_by_drift`; :func:`ssamb.closeloop.spectra.line_drift`), which a start-up course
   of the line shared by model and data does not bias;
2. by the **profile** of the fitting part's cost along the speed (:func:`speed_by_profile`): at
   each speed tried the effect's size parameters are solved by linear least squares
   (:func:`profile_point`), so that the cost compares speeds, not a size fitted at one speed and
   carried to the others. The size is refitted at the current speed, and the speed moves to the
   vertex of a parabola through the profile when the fitting part says it is better there;
3. the size's standard error includes the speed's: with :math:`s(f)` the profile's size and
   :math:`\sigma_f` the speed's error, :math:`\sigma_s^2 = \sigma_{s|f}^2 + (\partial s /
   \partial f)^2 \sigma_f^2` (the delta method; ``fixed["size_se_speed"]``, the slope of the
   profile's sizes over the steps tried, in the norm of the size parameters).
"""
from __future__ import annotations

import sys

import numpy as np
from scipy import stats

from .comparison import Comparison
from .fit import Base, improvement_z
from .spectra import line_drift

__all__ = ["refine_speeds", "speed_by_drift", "speed_by_profile", "profile_point", "parabola_vertex",
           "SPEED_DRIFT_Z", "SPEED_ITERATIONS", "SPEED_MAX_STEPS",
           "SPEED_REFINEMENTS"]

#: the drift over its standard error beyond which :func:`speed_by_drift` moves a line's speed
#: (a two-sided 5 % test of the measured speed against the model's own line)
SPEED_DRIFT_Z = 2.0
#: the most steps :func:`speed_by_drift` takes along the drift
SPEED_ITERATIONS = 3
#: the farthest :func:`speed_by_profile` steps out, in standard errors of the speed
SPEED_MAX_STEPS = 8.0
#: the parabolic refinements of the profile's least point in :func:`speed_by_profile`
SPEED_REFINEMENTS = 5


def _log(progress: bool, msg: str) -> None:
    if progress:
        sys.stderr.write(f"closeloop: {msg}\n")
        sys.stderr.flush()


def refine_speeds(cmp: Comparison, out, settings, progress: bool = False) -> None:
    r"""Estimate again the speed of every accepted effect whose frequency is measured, not fitted
    (module docstring), in the final model of ``out`` (a
    :class:`~ssamb.closeloop.search.SearchResult`, changed in place).

    A move is taken only when the data say the current speed is wrong (:data:`SPEED_DRIFT_Z`;
    the held-out improvement test's level ``alpha_accept`` on the fitting part).
    ``fit.speed_refined`` records the line's speed (``from_hz``), the final one (``to_hz``), and
    what moved it (``drift_se_hz`` and ``drift_z``; ``z_fit``)."""
    t_c = (cmp.fit.frame.i0 + cmp.fit.frame.n / 2) / cmp.record.fs_hz
    z_crit = float(stats.norm.isf(settings.alpha_accept))
    for a in out.accepted:
        fam = getattr(cmp.device.effects.get(a["model"].name), "neighbours", None)
        if fam is None or "speed_hz" not in a["model"].fixed:
            continue
        f_line = float(a["model"].fixed["speed_hz"])
        without = cmp.prediction(out.overrides, _effects(out, a, None, None))
        moved = {**speed_by_drift(cmp, out, a, fam, t_c, without, progress),
                 **speed_by_profile(cmp, out, a, fam, t_c, without, z_crit, progress)}
        if moved:
            a["speed_refined"] = {"from_hz": f_line, "to_hz": float(a["model"].fixed["speed_hz"]), **moved}


def _effects(out, a: dict, m, theta) -> list:
    """The final model's effects with ``a`` as ``(m, theta)`` (``m`` None: without ``a``)."""
    return [e for b in out.accepted
            for e in ((m.build(theta) if m is not None else []) if b is a else b["model"].build(b["theta"]))]


def _take(out, a: dict, m, th, pred, t_c: float) -> None:
    """Make ``(m, th)`` the accepted effect ``a``'s model in the final model (its phase pinned at
    ``t_c``; its prediction ``pred``)."""
    m.fixed["phase_t_s"] = t_c
    for k in ("speed_se_hz", "size_se_speed"):
        if k in a["model"].fixed and k not in m.fixed:
            m.fixed[k] = a["model"].fixed[k]
    out.effects = _effects(out, a, m, th)
    a["model"], a["theta"] = m, th
    out.final = pred


def _neighbour(cmp: Comparison, out, a: dict, fam, t_c: float, step: float) -> tuple | None:
    """The final model with ``a`` moved ``step`` of its speed's standard error along ``fam``:
    ``(model, theta, prediction)``, or None (no such speed, or the body dropped)."""
    got = fam(a["model"], a["theta"], t_c, [step])
    if not got:                                 # no such speed (at or below zero)
        return None
    m2, th2 = got[0]
    pred = cmp.prediction(out.overrides, _effects(out, a, m2, th2))
    return None if pred.get("delevitated_share", 0.0) > 0.5 else (m2, th2, pred)


def speed_by_drift(cmp: Comparison, out, a: dict, fam, t_c: float, without: dict, progress: bool = False) -> dict:
    r"""The speed of ``a`` moved by the drift of the data's phase against the final model's line
    (:func:`ssamb.closeloop.spectra.line_drift`; the line: the final model less ``without``, the
    same model without ``a``) when that drift exceeds :data:`SPEED_DRIFT_Z` of its standard
    error, then until what is left is below a quarter of it (at most :data:`SPEED_ITERATIONS`
    steps). The speed's reported standard error becomes the larger of the line's and the
    drift's, moved or not. Returns ``{"drift_se_hz", "drift_z"}`` when it moved, else ``{}``."""
    dev = cmp.device
    meas, wo = dev.views(cmp.record.channels), dev.views(without)

    def drift():
        pv = dev.views(out.final)
        return line_drift(cmp.fit.frame, {v: meas[v] - pv[v] for v in dev.view_names},
                          {v: pv[v] - wo[v] for v in dev.view_names}, float(a["model"].fixed["speed_hz"]))
    dr = drift()
    if dr is None:
        return {}
    se_line = float(a["model"].fixed.get("speed_se_hz", 0.0))
    z0, f0 = dr["delta_hz"] / dr["se_hz"], float(a["model"].fixed["speed_hz"])
    steps = 0
    if abs(z0) > SPEED_DRIFT_Z and se_line > 0:
        while steps < SPEED_ITERATIONS and dr is not None and abs(dr["delta_hz"]) >= 0.25 * dr["se_hz"]:
            got = _neighbour(cmp, out, a, fam, t_c, dr["delta_hz"] / float(a["model"].fixed["speed_se_hz"]))
            if got is None:
                break
            _take(out, a, *got, t_c)
            steps += 1
            dr = drift()
    se_d = float(dr["se_hz"]) if dr is not None else 0.0
    a["model"].fixed["speed_se_hz"] = max(se_line, se_d)
    a["model"].fixed["phase_t_s"] = t_c
    if not steps:
        return {}
    f1 = float(a["model"].fixed["speed_hz"])
    _log(progress, f"final model: {a['model'].name} at {f1:.6g} Hz instead of {f0:.6g} Hz: the data's phase drifts "
                   f"against the model's line by {f1 - f0:+.3g} Hz over the fitting part (se {se_d:.2g} Hz)")
    return {"drift_se_hz": se_d, "drift_z": float(z0)}


def profile_point(cmp: Comparison, out, a: dict, m, theta, without: dict) -> dict | None:
    r"""The effect ``a`` as ``(m, theta)`` with its size parameters solved by linear least squares
    on the fitting part: ``{"model", "theta", "cost", "size"}``, or None (the body dropped).

    The effect's response is linear in its size parameters :math:`c` (a force linear in them,
    through a loop linear at the response's amplitude), so the model's channels are
    :math:`x(c) = x_0 + \sum_i c_i (x_i - x_0)/s`, with :math:`x_0` the model without the
    effect (``without``) and :math:`x_i` a replay with size parameter :math:`i` alone at
    :math:`s = \lVert c_{\mathrm{size}}\rVert` (the largest finite-difference step where that is
    zero; one replay per size parameter). With the
    whitened residuals :math:`r_0` of :math:`x_0` and :math:`r_i` of :math:`x_i`, the solution
    is :math:`c = -s\,J^+ r_0`, :math:`J = [r_i - r_0]`; ``cost`` is :math:`\lVert r\rVert^2`
    of the channels :math:`x(c)` so made (their features computed as any replay's), ``size``
    :math:`\lVert c\rVert`."""
    idx = [list(m.params).index(p) for p in (m.size_params or m.params)]
    th = np.asarray(theta, float)
    s = float(np.linalg.norm(th[idx])) or float(np.max(np.asarray(m.step, float)[idx]))
    basis = []
    for i in idx:
        ti = th.copy()
        ti[idx] = 0.0
        ti[i] = s
        p = cmp.prediction(out.overrides, _effects(out, a, m, ti))
        if p.get("delevitated_share", 0.0) > 0.5:
            return None
        basis.append(p)
    r0 = cmp.residual(cmp.fit, without)
    jac = np.column_stack([cmp.residual(cmp.fit, p) - r0 for p in basis])
    coef = -np.linalg.lstsq(jac, r0, rcond=None)[0]
    sol = th.copy()
    sol[idx] = s * coef
    made = _combined(cmp, without, basis, coef)
    r = cmp.residual(cmp.fit, made)
    return {"model": m, "theta": sol, "cost": float(r @ r), "size": float(np.linalg.norm(sol[idx]))}


def _combined(cmp: Comparison, without: dict, basis: list, coef) -> dict:
    """The channels :math:`x_0 + \\sum_i c_i (x_i - x_0)` (and the replays' channels alike, when
    the comparison keeps them)."""
    def mix(x0, xs):
        return x0 + sum(c * (x - x0) for c, x in zip(coef, xs))
    out = dict(without)
    for ch in cmp.device.channels:
        if ch in without:
            out[ch] = mix(np.asarray(without[ch], float), [np.asarray(b[ch], float) for b in basis])
    if "runs" in without:
        out["runs"] = [{c: mix(np.asarray(r0[c], float), [np.asarray(b["runs"][j][c], float) for b in basis])
                        for c in r0} for j, r0 in enumerate(without["runs"])]
    return out


def speed_by_profile(cmp: Comparison, out, a: dict, fam, t_c: float, without: dict, z_crit: float,
                     progress: bool = False) -> dict:
    r"""The effect ``a`` refitted along its speed by the profile of the fitting part's cost
    (:func:`profile_point`, the size solved at each speed), in steps of the speed's standard
    error: the current speed and one step either side; the lowest end stepped out, the distance
    doubled, until the profile's least point has a neighbour on both sides (at most
    :data:`SPEED_MAX_STEPS` away); then the vertex of the parabola through that point and its
    neighbours (:func:`parabola_vertex`; the wider side halved where it would repeat a point),
    :data:`SPEED_REFINEMENTS` times. The size solved at
    the current speed is taken when its replay lowers the fitting part's cost; the profile's
    least point, replayed, when it improves the fitting part significantly
    (:func:`ssamb.closeloop.fit.improvement_z` above ``z_crit``: a replay's noise moves with the
    speed, and a cost lower by less is that noise). ``fixed["size_se_speed"]`` becomes the
    profile's change of the size per standard error of the speed about the final speed.
    Returns ``{"z_fit"}`` when the speed moved, else ``{}``."""
    m0, th0 = a["model"], a["theta"]
    prof: dict = {}

    def at(k):
        k = round(float(k), 3)
        if k not in prof:
            got = fam(m0, th0, t_c, [k])
            prof[k] = profile_point(cmp, out, a, *got[0], without) if got else None
        return prof[k]
    for k in (-1.0, 0.0, 1.0):
        at(k)
    best = _profile_search(prof, at)
    _log(progress, f"final model: {m0.name}'s profile along the speed (step: fitting chi2, size): "
                   + ", ".join(f"{k:+g}: {p['cost']:.1f}, {p['size']:.4g}" for k, p in sorted(prof.items()) if p))
    if prof.get(0.0) is not None:
        _refit_size(cmp, out, a, prof[0.0], t_c, progress)
    z, moved = None, {}
    if best is not None and best != 0.0:
        pt = prof[best]
        pred = cmp.prediction(out.overrides, _effects(out, a, pt["model"], pt["theta"]))
        eff = _effects(out, a, pt["model"], pt["theta"])
        if pred.get("delevitated_share", 0.0) <= 0.5:
            z = improvement_z(cmp, cmp.fit, Base(out.overrides, out.effects, out.final), pred, out.overrides, eff)
        if z is not None and z > z_crit:
            f0, f1 = float(m0.fixed["speed_hz"]), float(pt["model"].fixed["speed_hz"])
            _take(out, a, pt["model"], pt["theta"], pred, t_c)
            _log(progress, f"final model: {m0.name} at {f1:.6g} Hz instead of {f0:.6g} Hz: the fitting part's "
                           f"cost along the speed, its size solved at each, is least there (z {z:.1f})")
            moved = {"z_fit": float(z)}
    k1 = best if moved else 0.0
    lo, hi = at(k1 - 1.0), at(k1 + 1.0)
    if lo is not None and hi is not None:
        a["model"].fixed["size_se_speed"] = abs(hi["size"] - lo["size"]) / 2.0
    return moved


def _profile_search(prof: dict, at) -> float | None:
    """The step of the profile's least cost after bracketing and parabolic refinement
    (:func:`speed_by_profile`), ``prof`` filled by ``at(step)``; None without a point."""
    for _ in range(8):
        ok = sorted(k for k, p in prof.items() if p is not None)
        if len(ok) < 2:
            break
        kb = min(ok, key=lambda k: prof[k]["cost"])
        if kb == ok[0] and kb > -SPEED_MAX_STEPS:
            at(max(kb - 2 * (ok[1] - kb), -SPEED_MAX_STEPS))
        elif kb == ok[-1] and kb < SPEED_MAX_STEPS:
            at(min(kb + 2 * (kb - ok[-2]), SPEED_MAX_STEPS))
        else:
            break
    for _ in range(SPEED_REFINEMENTS):
        ok = sorted(k for k, p in prof.items() if p is not None)
        if len(ok) < 3:
            break
        i = min(range(len(ok)), key=lambda j: prof[ok[j]]["cost"])
        if i == 0 or i == len(ok) - 1:
            break
        v = parabola_vertex({k: (prof[k]["cost"], None) for k in ok[i - 1:i + 2]})
        if v is None or min(abs(v - k) for k in ok) < 0.05:     # the wider side halved instead
            lo, hi = ok[i] - ok[i - 1], ok[i + 1] - ok[i]
            if max(lo, hi) < 0.1:
                break
            v = ok[i] - lo / 2 if lo > hi else ok[i] + hi / 2
        at(v)
    ok = [k for k, p in prof.items() if p is not None]
    return min(ok, key=lambda k: prof[k]["cost"]) if ok else None


def _refit_size(cmp: Comparison, out, a: dict, pt: dict, t_c: float, progress: bool) -> None:
    """Take the size solved at the current speed (``pt``, :func:`profile_point`) when its replay
    costs the fitting part less than the final model."""
    pred = cmp.prediction(out.overrides, _effects(out, a, pt["model"], pt["theta"]))
    r0, r1 = cmp.residual(cmp.fit, out.final), cmp.residual(cmp.fit, pred)
    if float(r1 @ r1) < float(r0 @ r0) and pred.get("delevitated_share", 0.0) <= 0.5:
        idx = [list(a["model"].params).index(q) for q in (a["model"].size_params or a["model"].params)]
        before = float(np.linalg.norm(np.asarray(a["theta"], float)[idx]))
        _take(out, a, pt["model"], pt["theta"], pred, t_c)
        _log(progress, f"final model: {a['model'].name}'s size solved at its speed: {pt['size']:.4g} "
                       f"(was {before:.4g}), fitting part chi2 {float(r0 @ r0):.1f} -> {float(r1 @ r1):.1f}")


def parabola_vertex(tried: dict) -> float | None:
    """The vertex of the parabola fitted by least squares to every cost of ``tried`` (``step ->
    (cost, ...)``), when it is a minimum within the steps tried; else None."""
    ks = np.array(sorted(tried))
    if len(ks) < 3:
        return None
    c2, c1, _ = np.polyfit(ks, [tried[k][0] for k in ks], 2)
    if c2 <= 0:
        return None
    v = float(-c1 / (2 * c2))
    return round(v, 3) if ks[0] < v < ks[-1] else None
