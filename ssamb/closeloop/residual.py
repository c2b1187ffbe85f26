r"""Residual analysis: errors, offsets, lines, excited-line ratios, cross-axis, ripple.

The residual of a view :math:`v` is :math:`e_v = y_v - \hat y_v` (measured minus model).
:func:`compute_features` turns it, over one analysis segment (the fitting part or the held-out
part), into the evidence the effect signatures read:

* **noise floor** per view (:func:`ssamb.closeloop.spectra.noise_floor`) and its white-
  equivalent :math:`\sigma_v`, never below a floor (a noise-free logged channel);
* **offsets** :math:`\hat\mu_v` with :math:`z_v = \hat\mu_v / \mathrm{SE}_v`;
* **lines** the excitation lacks (off-grid for a periodic excitation), refined in frequency,
  with the phasor in every view;
* **excited-line residual** :math:`\chi^2_v = \sum_k |E_v(k)|^2 / S_v(k)` over the excited
  bins (the frequency-domain form of the residual-input cross-correlation test; under noise
  alone it is Gamma(K, 1));
* **sensor-path ratio** per excited axis, the measured over the modelled ratio of sensor to
  coil current at the excited lines,

  .. math:: R(f) = \frac{Y_s(f)/Y_i(f)}{\hat Y_s(f)/\hat Y_i(f)}, \qquad
            \ln R(f) \approx \alpha - j 2\pi f \tau ,

  whose flat log-gain :math:`\alpha` is a sensor gain error and whose phase slope
  :math:`\tau` a sensor delay (weighted least squares, standard errors inflated by the
  reduced :math:`\chi^2` of the fit);
* **cross-axis** evidence: residual in axis b coherent with the excitation of axis a beyond
  what b's own nominal response explains (an F-test on a smooth two-input regression across
  the excited lines);
* **ripple distortion**: residual of the coil currents on the periodic grid above
  ``ripple_min_hz`` (where the excitation puts nothing but the PWM sampling pattern);
* **windows**: the residual's means over consecutive windows (whole periods of a periodic
  excitation, else the Welch hop of :func:`ssamb.closeloop.features.make_layout`), each with the
  standard error its length gives at the low-frequency noise floor (that of the offsets):
  :math:`\mathrm{SE}_w^2 = S(0^+)/(W_2 L)`; ``chi2`` of the windows about zero and
  ``chi2_trend`` about their weighted mean (slow trends: a response to a slowly varying
  reference the model misses, a drift);
* **bands** (the device's band views): :math:`\ln(\hat P_{meas}/\hat P_{model})` per band of
  Welch bins without excitation power (:func:`ssamb.closeloop.features.band_plan`), the modelled
  density the mean over the replays' densities, each log bias-corrected for its degrees of
  freedom, with the standard error :math:`\sqrt{\psi'(\nu/2) + \psi'(m\nu/2)}` (the loop's
  response to its own noise).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .spectra import (Frame, dft, find_peaks_bins, fit_line, lasts, noise_floor, offset, welch_transfer,
                      white_sigma)

__all__ = ["Features", "compute_features", "channel_errors", "channel_noise"]



@dataclass
class Features:
    """Evidence extracted from a residual over one segment (see module docstring)."""

    frame: Frame
    sigma: dict
    S: dict
    X: dict
    offsets: dict = field(default_factory=dict)
    lines: list = field(default_factory=list)
    excited_residual: dict = field(default_factory=dict)
    ratios: dict = field(default_factory=dict)
    cross: dict = field(default_factory=dict)
    ripple: dict = field(default_factory=dict)
    device: dict = field(default_factory=dict)
    floor: dict = field(default_factory=dict)
    excited_f_hz: np.ndarray = field(default_factory=lambda: np.zeros(0))
    windows: dict = field(default_factory=dict)
    bands: dict = field(default_factory=dict)


def _floor(view: str, model_seg: np.ndarray, settings, dev) -> float:
    absf = dev.floors(settings)[view]
    return max(absf, settings.floor_relative * float(np.std(model_seg)))


def channel_errors(meas: dict, model: dict, sl: slice, dev, sigma: dict | None = None) -> dict:
    r"""Held-out error of every channel of the device and of its groups (:attr:`Device.error_groups`).

    ``rms`` is :math:`\sqrt{\overline{e^2}}` and ``fit_pct`` the NRMSE fit
    :math:`100\,(1 - \|y - \hat y\| / \|y - \bar y\|)`; a group (the AMB's ``currents``)
    pools its channels.
    """
    out = {}
    for c in dev.channels:
        y, yh = meas[c][sl], model[c][sl]
        e = y - yh
        den = np.linalg.norm(y - y.mean())
        d = {"rms": float(np.sqrt(np.mean(e ** 2))),
             "fit_pct": float(100.0 * (1.0 - np.linalg.norm(e) / den)) if den > 0 else float("nan"),
             "mean": float(np.mean(e))}
        if sigma is not None and c in sigma:
            d["noise_rms"] = float(sigma[c])
        out[c] = d
    for name, group in dev.error_groups.items():
        e = np.concatenate([meas[c][sl] - model[c][sl] for c in group])
        y = np.concatenate([meas[c][sl] - meas[c][sl].mean() for c in group])
        ny = np.linalg.norm(y)
        cur = {"rms": float(np.sqrt(np.mean(e ** 2))),
               "fit_pct": float(100.0 * (1.0 - np.linalg.norm(e) / ny)) if ny > 0 else float("nan"),
               "per_coil": {c: out[c] for c in group}}
        if sigma is not None:
            cur["noise_rms"] = float(np.sqrt(np.mean([sigma[c] ** 2 for c in group])))
        out[name] = cur
    return out


def _line_floor(frame: Frame, S: np.ndarray, fl: float) -> np.ndarray:
    """Noise floor plus a line of amplitude ``fl`` (the reproducibility floor) in every bin."""
    return S + (fl * float(np.sum(frame.window)) / 2.0) ** 2


def _gamma_p(chi: float, k: int) -> float:
    return float(stats.gamma.sf(chi, k)) if k > 0 else 1.0


def _gamma_logp(chi: float, k: int) -> float:
    """log of the Gamma(k, 1) survival function, with the large-argument asymptote where it underflows."""
    if k <= 0:
        return 0.0
    lp = float(stats.gamma.logsf(chi, k))
    if not math.isfinite(lp):
        lp = -chi + (k - 1) * math.log(chi) - math.lgamma(k)
    return lp


def _excited_data(rec, frame: Frame, meas_v: dict, model_v: dict, S: dict, X: dict, Xm: dict, Xh: dict,
                  fl: dict | None = None):
    """Per excited axis: bins, excitation DFT, measured/model values and noise variance per view."""
    out = {}
    vn = rec.device.view_names
    if frame.periodic:
        for ax, kb in frame.excited.items():
            if len(kb) == 0:
                continue
            Sa = np.fft.rfft(rec.signal[ax][frame.i0:frame.i0 + frame.n])[kb]
            d = {"f_hz": frame.f_hz[kb], "bins": kb, "Hm": {}, "Hh": {}, "var": {}, "E": {}, "Enoise": {}}
            for v in vn:
                d["Hm"][v] = Xm[v][kb] / Sa
                d["Hh"][v] = Xh[v][kb] / Sa
                d["var"][v] = S[v][kb] / np.abs(Sa) ** 2
                d["E"][v] = X[v][kb] / Sa            # residual per unit excitation
                d["Enoise"][v] = d["var"][v]
            out[ax] = d
        return out
    seg = slice(frame.i0, frame.i0 + frame.n)
    nper = int(2 ** max(8, min(16, int(math.log2(max(frame.n // 8, 256))))))
    if nper > frame.n // 2:             # a short record: segments of at most half its length
        nper = int(2 ** max(4, int(math.log2(max(frame.n // 2, 16)))))
    for ax in rec.excited_axes:
        s = rec.signal[ax][seg]
        wm = welch_transfer(s, {v: meas_v[v][seg] for v in vn}, rec.fs_hz, nper)
        wh = welch_transfer(s, {v: model_v[v][seg] for v in vn}, rec.fs_hz, nper)
        # the noise of a measured transfer is the part of the residual not coherent with the
        # excitation (the model's own nonlinear response is shared by data and model)
        wr = welch_transfer(s, {v: meas_v[v][seg] - model_v[v][seg] for v in vn}, rec.fs_hz, nper)
        sel = (wm["f_hz"] > 0) & (wm["Sss"] > 1e-3 * wm["Sss"].max())
        if not np.any(sel):
            continue
        d = {"f_hz": wm["f_hz"][sel], "bins": np.flatnonzero(sel), "Hm": {}, "Hh": {}, "var": {}, "E": {}, "Enoise": {},
             # neighbouring Hann bins are correlated: a chi^2 sum over k bins is ~ 1.5 Gamma(k/1.5)
             "chi_scale": 1.5}
        for v in vn:
            d["Hm"][v] = wm["H"][v][sel]
            d["Hh"][v] = wh["H"][v][sel]
            # never below the reproducibility floor, seen as white noise of that level
            v_fl = 2.0 * (fl or {}).get(v, 0.0) ** 2 / rec.fs_hz / (wr["k_eff"] * wm["Sss"][sel])
            d["var"][v] = np.maximum(np.maximum(wr["var"][v][sel], v_fl), 1e-300)
            d["E"][v] = d["Hm"][v] - d["Hh"][v]
            d["Enoise"][v] = d["var"][v]
        out[ax] = d
    return out


def _isolated_excited_lines(frame: Frame, X: dict, S: dict, exd: dict, alpha: float, dev,
                            isolation: float = 100.0) -> list:
    """Lines that sit on an excited line but stand out of it: residual at one excited bin, in
    every line view (:attr:`FeatureSpec.line_views`: the AMB's two axes), ``isolation`` times (in
    chi^2) above the median of the other excited bins (an unbalance spinning at an excited
    frequency; periodic frames only)."""
    vn = dev.view_names
    lv = dev.features.line_views
    kb = np.unique(np.concatenate([d["bins"] for d in exd.values()]))
    if len(kb) < 5:
        return []
    thr = math.log(2 * len(kb) / alpha)
    chi = {v: np.abs(X[v][kb]) ** 2 / S[v][kb] for v in vn}
    out = []
    for i, k in enumerate(kb):
        ok = True
        for v in lv:
            others = np.delete(chi[v], i)
            if not (chi[v][i] > thr and chi[v][i] > isolation * max(np.median(others), 1.0)):
                ok = False
        if ok:
            out.append({"f_hz": float(frame.f_hz[k]), "phasor": {v: complex(2 * X[v][k] / frame.n) for v in vn},
                        "se": {v: math.sqrt(2 * S[v][k]) / frame.n for v in vn},
                        "chi2": {v: float(chi[v][i]) for v in vn}, "views_detected": list(lv),
                        "peak_ratio": float(min(chi[v][i] for v in lv)), "threshold": thr,
                        "on_excited_line": True})
    return out


def _ratio_fit(f_hz, Hm_s, Hm_a, Hh_s, Hh_a, var_s, var_a, min_snr: float = 10.0) -> dict | None:
    r"""Weighted fit of :math:`\ln R = \alpha - j 2\pi f\tau` to the sensor-path ratio."""
    snr_s = np.abs(Hm_s) ** 2 / var_s
    snr_a = np.abs(Hm_a) ** 2 / var_a
    ok = (snr_s > min_snr ** 2) & (snr_a > min_snr ** 2) & (np.abs(Hh_s) > 0) & (np.abs(Hh_a) > 0)
    if np.count_nonzero(ok) < 3:
        return None
    f = f_hz[ok]
    R = (Hm_s[ok] / Hm_a[ok]) / (Hh_s[ok] / Hh_a[ok])
    var_ln = var_s[ok] / np.abs(Hm_s[ok]) ** 2 + var_a[ok] / np.abs(Hm_a[ok]) ** 2
    w = 2.0 / var_ln                       # per real component
    order = np.argsort(f)
    f, R, w = f[order], R[order], w[order]
    lnr = np.log(np.abs(R))
    ph = np.unwrap(np.angle(R))
    om = 2 * np.pi * f
    k = len(f)
    alpha = float(np.sum(w * lnr) / np.sum(w))
    tau = float(-np.sum(w * om * ph) / np.sum(w * om ** 2))
    chi_re = float(np.sum(w * (lnr - alpha) ** 2))
    chi_im = float(np.sum(w * (ph + om * tau) ** 2))
    se_a0 = math.sqrt(1.0 / np.sum(w))
    se_t0 = math.sqrt(1.0 / np.sum(w * om ** 2))
    se_a = se_a0 * math.sqrt(max(1.0, chi_re / max(k - 1, 1)))
    se_t = se_t0 * math.sqrt(max(1.0, chi_im / max(k - 1, 1)))
    return {"f_hz": f, "R": R, "var_ln": 2.0 / w, "alpha": alpha, "se_alpha": se_a, "z_alpha": alpha / se_a,
            "gain": math.exp(alpha), "tau_s": tau, "se_tau_s": se_t, "z_tau": tau / se_t,
            "chi2_alpha": (alpha / se_a0) ** 2, "chi2_tau": (tau / se_t0) ** 2,
            "chi2_gain": chi_re, "chi2_phase": chi_im, "dof": k - 1, "n_lines": k}


def _cross_test(exd: dict, a: str, b: str, dev, degree: int = 2) -> dict | None:
    r"""Residual in axis ``b`` explained by axis ``a`` beyond b's own nominal response.

    For each view v of b, at the excited lines: :math:`E_v(k) = \sum_i c_i \phi_i(f_k)\hat Y_v(k)
    + \sum_i d_i \phi_i(f_k) \hat Y_{a}(k)` with :math:`\phi_i = (f/f_{max})^i` and
    :math:`\hat Y_a` the model's counterpart view of axis a; F-test of :math:`d = 0` (weights
    :math:`1/S_v(k)`). When b is not excited, the test is simply the residual of b at a's
    excited lines (:math:`\chi^2`, Gamma distribution).
    """
    src = exd.get(a)
    if src is None:
        return None
    axis_views, counterpart = dev.features.axis_views, dev.features.counterpart
    f = src["f_hz"]
    fn = f / max(f.max(), 1e-12)
    best = None
    for v in axis_views[b]:
        E = src["E"][v]
        Sn = src["Enoise"][v]
        wts = 1.0 / np.sqrt(Sn)
        own = src["Hh"][v]
        oth = src["Hh"][counterpart[v]]
        k = len(f)
        if b not in exd:
            chi = float(np.sum(np.abs(E) ** 2 / Sn))
            c = src.get("chi_scale", 1.0)
            lp = _gamma_logp(chi / c, max(int(round(k / c)), 1))
            res = {"view": v, "p": math.exp(lp), "logp": lp, "stat": chi, "kind": "chi2", "k": k,
                   "delta_chi2": max(chi - k, 0.0)}
        else:
            if 2 * k <= 4 * (degree + 1) + 2:
                continue
            own_n = own / (np.sqrt(np.mean(np.abs(own) ** 2)) or 1.0)
            oth_n = oth / (np.sqrt(np.mean(np.abs(oth) ** 2)) or 1.0)
            A0 = np.column_stack([fn ** i * own_n for i in range(degree + 1)]) * wts[:, None]
            A1 = np.column_stack([fn ** i * oth_n for i in range(degree + 1)]) * wts[:, None]
            y = E * wts

            def rss(A):
                Ar = np.vstack([np.hstack([A.real, -A.imag]), np.hstack([A.imag, A.real])])
                yr = np.concatenate([y.real, y.imag])
                sol, *_ = np.linalg.lstsq(Ar, yr, rcond=None)
                return float(np.sum((yr - Ar @ sol) ** 2)), Ar.shape[1]

            r0, p0 = rss(A0)
            r1, p1 = rss(np.hstack([A0, A1]))
            n_obs = 2 * k
            q = p1 - p0
            dof = n_obs - p1
            if r1 <= 0 or dof <= 0:
                continue
            F = ((r0 - r1) / q) / (r1 / dof)
            lp = float(stats.f.logsf(F, q, dof))
            res = {"view": v, "p": math.exp(lp), "logp": lp, "stat": float(F), "kind": "F", "q": q, "dof": dof,
                   "explained": float((r0 - r1) / r0) if r0 > 0 else 0.0,
                   "delta_chi2": float(max(r0 - r1 - q, 0.0))}
        if best is None or res["logp"] < best["logp"]:
            best = res
    if best is not None:
        best["n_views"] = len(axis_views[b])
    return best


def _spectra_of(frame: Frame, meas_v: dict, model_v: dict, settings, dev):
    """Residual, DFTs (residual, measured, model), reproducibility floors and noise floors per view."""
    seg = slice(frame.i0, frame.i0 + frame.n)
    vn = dev.view_names
    res_v = {v: meas_v[v] - model_v[v] for v in vn}
    fl = {v: _floor(v, model_v[v][seg], settings, dev) for v in vn}
    X = {v: dft(frame, res_v[v]) for v in vn}
    Xm = {v: dft(frame, meas_v[v]) for v in vn}
    Xh = {v: dft(frame, model_v[v]) for v in vn}
    S = {v: noise_floor(frame, X[v], floor=fl[v]) for v in vn}
    return res_v, fl, X, Xm, Xh, S


def _find_lines(frame: Frame, res_v: dict, X: dict, S: dict, fl: dict, settings, dev,
                device_lines_hz=()) -> tuple[list, dict]:
    """Lines the excitation lacks: detect, remove, re-estimate the floor, detect again (a strong
    line leaks into the off-grid bins of a rectangular frame and would raise the floor).

    Updates ``X`` and ``S`` in place (lines removed); returns the lines and the segments with
    them removed."""
    seg = slice(frame.i0, frame.i0 + frame.n)
    vn = dev.view_names
    segs = {v: res_v[v][seg].copy() for v in vn}
    found, detected = [], []
    for _pass in range(2):
        P = {v: np.abs(X[v]) ** 2 for v in vn}
        Sl = {v: _line_floor(frame, S[v], fl[v]) for v in vn}
        clusters = find_peaks_bins(frame, P, Sl, 0.0, settings.line_search_max_hz, settings.alpha_evidence,
                                   exclude_hz=np.asarray(device_lines_hz, float))
        clusters = [c for c in clusters if all(abs(c["f_hz"] - ln["f_hz"]) > 2 * frame.df_hz for ln in found)]
        # inside the range a sweep passes once, only a line that lasts (not the sweep's transient)
        pm = frame.passing_mask
        clusters = [c for c in clusters if pm is None or not pm[c["bin"]]
                    or lasts(frame, segs[max(c["views"], key=c["views"].get)], c["f_hz"])]
        if not clusters:
            break
        for c in clusters[:6]:
            sig_at = {v: math.sqrt(S[v][c["bin"]] / frame.w2) for v in vn}
            ln = fit_line(frame, segs, sig_at, c["f_hz"])
            ln.update(views_detected=sorted(c["views"]), peak_ratio=c["peak"], threshold=c["threshold"])
            found.append(ln)
            detected.append(c["f_hz"])
            for v in vn:
                segs[v] = segs[v] - ln["component"][v]
        for v in vn:
            full = res_v[v].copy()
            full[seg] = segs[v]
            X[v] = dft(frame, full)
            S[v] = noise_floor(frame, X[v], floor=fl[v])
    for i, ln in enumerate(found):
        # each line fitted again against the floor without the lines: the floor it was detected
        # on holds its own leakage (a strong line's the most), which would weight the views where
        # it stands clearest least
        k = min(int(round(ln["f_hz"] / frame.df_hz)), len(S[vn[0]]) - 1)
        back = {v: segs[v] + ln["component"][v] for v in vn}
        new = fit_line(frame, back, {v: math.sqrt(S[v][k] / frame.w2) for v in vn}, detected[i])
        new.update({key: ln[key] for key in ("views_detected", "peak_ratio", "threshold")})
        found[i] = new
        segs = {v: back[v] - new["component"][v] for v in vn}
    if found:
        for v in vn:
            full = res_v[v].copy()
            full[seg] = segs[v]
            X[v] = dft(frame, full)
            S[v] = noise_floor(frame, X[v], floor=fl[v])
    for ln in found:          # final amplitudes against the final floor
        k = int(round(ln["f_hz"] / frame.df_hz))
        for v in vn:
            se = math.hypot(math.sqrt(S[v][min(k, len(S[v]) - 1)] / frame.w2) * ln["se_scale"], fl[v])
            ln["se"][v] = se
            ln["chi2"][v] = abs(ln["phasor"][v]) ** 2 / se ** 2 if se > 0 else float("inf")
    return found, segs


def _remove_lines(frame: Frame, res_v: dict, meas_v: dict, Xm: dict, segs: dict) -> dict:
    """Residual and measurement with the found lines removed (for everything after the lines)."""
    seg = slice(frame.i0, frame.i0 + frame.n)
    meas_v = dict(meas_v)
    for v in segs:
        comp = np.zeros_like(res_v[v])
        comp[seg] = res_v[v][seg] - segs[v]
        res_v[v] = res_v[v] - comp
        meas_v[v] = meas_v[v] - comp
        Xm[v] = dft(frame, meas_v[v])
    return meas_v


def _excited_residual(exd: dict, views: tuple) -> dict:
    """Per view, the chi-square of the residual at the excited lines (each bin once) and its p."""
    out = {}
    for v in views:
        chi, k, seen, c = 0.0, 0, set(), 1.0
        for d in exd.values():
            c = d.get("chi_scale", 1.0)
            for i, b in enumerate(d["bins"]):
                if int(b) not in seen:
                    seen.add(int(b))
                    chi += float(np.abs(d["E"][v][i]) ** 2 / d["Enoise"][v][i])
                    k += 1
        out[v] = {"chi2": chi, "k": k, "p": _gamma_p(chi / c, max(int(round(k / c)), 1)) if k else 1.0,
                  "excess_ratio": chi / k - 1.0 if k else 0.0}
    return out


def _paths(ft: Features, exd: dict, settings, dev) -> None:
    """The device's path ratios (:attr:`FeatureSpec.paths`) at each excited axis' lines, and the
    cross-axis tests between its axes (into ``ft``)."""
    for ax, d in exd.items():
        for name, (pax, sv, va) in dev.features.paths.items():
            if pax != ax:
                continue
            r = _ratio_fit(d["f_hz"], d["Hm"][sv], d["Hm"][va], d["Hh"][sv], d["Hh"][va], d["var"][sv], d["var"][va],
                           settings.ratio_min_snr)
            if r is not None:
                r["axis"], r["path"] = ax, f"{sv}/{va}"
                ft.ratios[name] = r
    axes = tuple(dev.features.axis_views)
    for a, b in ((a, b) for a in axes for b in axes if a != b):
        c = _cross_test(exd, a, b, dev)
        if c is not None:
            ft.cross[f"{a}->{b}"] = c


def _ripple(frame: Frame, X: dict, Sl: dict, settings, views: tuple) -> dict:
    """Ripple distortion: residual chi-square of the coil currents on the grid above ``ripple_min_hz``."""
    sel = frame.grid_mask & (frame.f_hz >= settings.ripple_min_hz)
    k = int(np.count_nonzero(sel))
    out = {}
    for v in views:
        chi = float(np.sum(np.abs(X[v][sel]) ** 2 / Sl[v][sel]))
        out[v] = {"chi2": chi, "k": k, "p": _gamma_p(chi, k), "excess_ratio": chi / k - 1.0 if k else 0.0}
    return out


def _device_lines(frame: Frame, X: dict, Sl: dict, lines_hz, views: tuple, res_v: dict | None = None,
                  fl: dict | None = None) -> dict:
    r"""Residual chi-square of the coil-current views at the device's own lines (the PWM carrier's
    aliased harmonics): the ripple's shape, which a dead time changes and the bias current does not.

    A periodic frame reads them on its grid (the DFT bins). Another frame fits each line's phasor
    by least squares at its exact frequency (:func:`ssamb.closeloop.features.line_phasors`, the
    segment's mean removed) and weighs it with the noise floor of the Hann-tapered DFT there:
    a phasor :math:`A` of a rectangular :math:`n`-sample fit has variance :math:`S(k)\,n/W_2` (and
    the model's reproducibility floor as a line, :math:`(f_l n/2)^2`); :math:`|A|^2` over it is
    exponential under noise alone, as a periodic frame's bin.
    """
    out = {}
    if frame.periodic:
        kb = [int(round(f / frame.df_hz)) for f in lines_hz
              if abs(f / frame.df_hz - round(f / frame.df_hz)) < 1e-6 and round(f / frame.df_hz) < len(frame.f_hz)]
        for v in views:
            chi = float(np.sum(np.abs(X[v][kb]) ** 2 / Sl[v][kb])) if kb else 0.0
            out[v] = {"chi2": chi, "k": len(kb), "logp": float(stats.chi2.logsf(2 * chi, 2 * len(kb))) if kb else 0.0}
        return out
    from .features import line_phasors

    fs = [float(f) for f in lines_hz if 0 < f < frame.fs_hz / 2 - 2 * frame.df_hz]
    if res_v is None or not fs:
        return {v: {"chi2": 0.0, "k": 0, "logp": 0.0} for v in views}
    seg = slice(frame.i0, frame.i0 + frame.n)
    x = np.stack([np.asarray(res_v[v], float)[seg] for v in views])
    A = line_phasors(frame, x, fs)                       # lines x views
    kb = [min(int(round(f / frame.df_hz)), len(frame.f_hz) - 1) for f in fs]
    for j, v in enumerate(views):
        S = np.array([float(Sl[v][k]) for k in kb])
        # Sl holds the Hann DFT's floor plus the reproducibility floor as a Hann line, (fl sum w / 2)^2;
        # the rectangular fit's variance: the floor's noise part scaled by n / W2, the line part as (fl n / 2)^2
        line = ((fl or {}).get(v, 0.0) * float(np.sum(frame.window)) / 2.0) ** 2
        var = np.maximum(S - line, 0.0) * frame.n / frame.w2 + ((fl or {}).get(v, 0.0) * frame.n / 2.0) ** 2
        chi = float(np.sum(np.abs(A[:, j]) ** 2 / np.maximum(var, 1e-300)))
        out[v] = {"chi2": chi, "k": len(fs), "logp": float(stats.chi2.logsf(2 * chi, 2 * len(fs)))}
    return out


def channel_noise(frame: Frame, meas_ch: dict, model_ch: dict, settings, dev) -> dict:
    """White-equivalent noise level of every channel's residual over ``frame`` (off-grid floor)."""
    seg = slice(frame.i0, frame.i0 + frame.n)
    return {c: white_sigma(frame, noise_floor(frame, dft(frame, meas_ch[c] - model_ch[c]),
                                              floor=_floor(c, model_ch[c][seg], settings, dev)))
            for c in dev.channels}


def _windows(frame: Frame, res_v: dict, S: dict, fl: dict, views) -> dict:
    """The residual's window means (module docstring): whole periods of a periodic frame (at least
    three), else the Welch hop of the frame's layout."""
    from .features import _welch_length

    if frame.periodic:
        L = frame.n_period
    else:
        L = max(_welch_length(frame.n) // 2, 1)
    W = frame.n // L
    if W < 3:
        return {}
    L = frame.n // W
    t = (frame.i0 + (np.arange(W) + 0.5) * L) / frame.fs_hz
    out = {}
    for v in views:
        seg = res_v[v][frame.i0:frame.i0 + W * L]
        mean = seg.reshape(W, L).mean(axis=1)
        se = math.hypot(math.sqrt(max(S[v][1], 0.0) / (frame.w2 * L)) if len(S[v]) > 1 else 0.0, fl[v])
        z = mean / se if se > 0 else np.zeros(W)
        out[v] = {"t_s": t, "mean": mean, "se": np.full(W, se), "chi2": float(np.sum(z ** 2)), "k": W,
                  "chi2_trend": float(np.sum((z - z.mean()) ** 2)), "window_s": L / frame.fs_hz}
    return out


def _bands(rec, frame: Frame, meas_v: dict, model_v: dict, model_runs, fl: dict) -> dict:
    """ln of the measured over the modelled density in bands, per band view (module docstring)."""
    from .features import Layout, _band_spectra, _welch_length, band_dof, band_plan, log_bias, log_var

    views = tuple(getattr(rec.device.features, "band_views", ()) or ())
    if not views:
        return {}
    nper = _welch_length(frame.n)
    bands = band_plan(frame, rec.signal, nper, getattr(rec, "device_lines_hz", ()))
    if not bands:
        return {}
    lay = Layout(frame, np.zeros(0, int), (), 0, (), views, band_views=views, bands=tuple(bands), band_nper=nper,
                 band_floor=tuple(2.0 * fl[v] ** 2 / frame.fs_hz for v in views))
    seg = slice(frame.i0, frame.i0 + frame.n)
    runs = model_runs or [model_v]
    xm = [np.stack([np.asarray(meas_v[v], float)[seg] for v in views])]
    xh = [np.stack([np.asarray(r[v], float)[seg] for v in views]) for r in runs]
    (Cm, scale, n_seg), (Ch, _, _) = _band_spectra(lay, xm), _band_spectra(lay, xh)
    sizes = np.array([len(b) for b in bands], float)
    floor = np.asarray(lay.band_floor, float)
    Pm = np.real(np.einsum("bvv->bv", Cm)) * scale / sizes[:, None] + floor
    Ph = np.real(np.einsum("bvv->bv", Ch)) * scale / sizes[:, None] + floor
    nu = np.array([band_dof(b, n_seg) for b in bands])
    m = len(runs)
    lr = (np.log(Pm) - np.array([log_bias(x) for x in nu])[:, None]) - \
        (np.log(Ph) - np.array([log_bias(m * x) for x in nu])[:, None])
    se = np.sqrt(np.array([log_var(x) + log_var(m * x) for x in nu]))
    f = np.array([float(np.mean(b)) * frame.fs_hz / nper for b in bands])
    out = {}
    for j, v in enumerate(views):
        z = lr[:, j] / se
        out[v] = {"f_hz": f, "log_ratio": lr[:, j], "se": se, "chi2": float(np.sum(z ** 2)), "k": len(bands),
                  "dof": nu, "replays": m}
    return out


def compute_features(rec, frame: Frame, meas_v: dict, model_v: dict, settings, lines: bool = True,
                     model_runs: list | None = None) -> Features:
    """Evidence of the residual ``meas_v - model_v`` (views, whole-record arrays) over ``frame``
    (module docstring). ``model_runs`` (the view dicts of the replays whose mean ``model_v`` is)
    give the modelled densities of the ``bands``; without them ``model_v`` counts as one
    replay."""
    dev = rec.device
    vn = dev.view_names
    res_v, fl, X, Xm, Xh, S = _spectra_of(frame, meas_v, model_v, settings, dev)
    found = []
    if lines:
        found, segs = _find_lines(frame, res_v, X, S, fl, settings, dev, getattr(rec, "device_lines_hz", ()))
        if found:
            meas_v = _remove_lines(frame, res_v, meas_v, Xm, segs)
        for ln in found:
            ln.pop("component", None)
    ft = Features(frame=frame, sigma={v: white_sigma(frame, S[v]) for v in vn}, S=S, X=X)
    ft.lines, ft.floor = found, fl
    # deterministic content below the model's reproducibility floor is not evidence: the line
    # tests see the floor as a line of amplitude fl in every bin
    Sl = {v: _line_floor(frame, S[v], fl[v]) for v in vn}
    for v in vn:
        mu, se = offset(frame, res_v[v], S[v])
        se = math.hypot(se, fl[v])
        ft.offsets[v] = {"mean": mu, "se": se, "z": mu / se if se > 0 else 0.0}
    ft.windows = _windows(frame, res_v, S, fl, vn)
    ft.bands = _bands(rec, frame, meas_v, model_v, model_runs, fl)
    exd = _excited_data(rec, frame, meas_v, model_v, Sl, X, Xm, Xh, fl)
    ft.excited_f_hz = np.unique(np.concatenate([d["f_hz"] for d in exd.values()])) if exd else np.zeros(0)
    ft.excited_residual = _excited_residual(exd, vn)
    if lines and frame.periodic and exd:
        ft.lines.extend(_isolated_excited_lines(frame, X, Sl, exd, settings.alpha_evidence, dev,
                                                 settings.line_isolation))
    _paths(ft, exd, settings, dev)
    rv = dev.features.ripple_views
    if frame.periodic:
        ft.ripple = _ripple(frame, X, Sl, settings, rv) if rv else {}
    ft.device = _device_lines(frame, X, Sl, getattr(rec, "device_lines_hz", ()), rv, res_v, fl) if rv else {}
    return ft
