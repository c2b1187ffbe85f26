"""Features that work on any record: windows (slow trends) and bands (log power spectral densities)
with their noise, on records without a periodic excitation or without any excitation at all."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from ssamb.closeloop.features import (Whitener, band_dof, band_plan, features, log_bias, log_var, make_layout,
                                      replicate_factors, scale_views)
from ssamb.closeloop.spectra import make_frame
from ssamb.device import Device, EffectModel, FeatureSpec, Record, Replay

FS = 1000.0


def _ar1(rng, n, a=0.9, s=1.0):
    return signal.lfilter([s], [1.0, -a], rng.standard_normal(n))


def test_band_dof_matches_the_spread_of_the_log_density():
    """The log of a band's mean Welch density of white noise scatters with the trigamma of half
    its degrees of freedom (Hann, half-overlapping segments, adjacent bins correlated), and its
    mean is the log of the true density plus the digamma bias."""
    rng = np.random.default_rng(3)
    n, nper = 4096, 256
    fr = make_frame(FS, 0, n, {}, None, None)
    bands = band_plan(fr, {}, nper)
    assert len(bands) >= 8 and all(len(b) >= 4 for b in bands)
    lay = SimpleNamespace(views=("a",), band_views=("a",), band_nper=nper, bands=tuple(bands), frame=fr,
                          band_floor=(0.0,))
    from ssamb.closeloop.features import _band_values

    vals = np.array([_band_values(lay, [rng.standard_normal((1, n))], False)[0][:, 0] for _ in range(300)])
    n_seg = (n - nper) // (nper // 2) + 1
    nu = np.array([band_dof(b, n_seg) for b in bands])
    pred = np.array([log_var(x) for x in nu])
    ratio = vals.var(axis=0, ddof=1) / pred
    assert 0.8 < np.median(ratio) < 1.2, ratio
    # white noise of unit variance: one-sided density 2 / fs, the bias already removed
    assert np.mean(vals) == pytest.approx(math.log(2.0 / FS), abs=0.03)
    assert log_bias(1e6) == pytest.approx(0.0, abs=1e-5) and log_bias(10.0) < -0.09


def test_bands_whitened_difference_has_unit_variance_and_sees_a_louder_loop():
    """Data and the mean density of 8 replays of the same coloured noise: the whitened band
    difference has unit variance (coherent views included); data 30 % louder in one view give
    a chi-square far above its entries there."""
    rng = np.random.default_rng(5)
    n = 8192
    fr = make_frame(FS, 0, n, {}, None, None)
    lay = make_layout(fr, {}, views=("y", "u"), band_views=("y", "u"))
    assert lay.bands and lay.n_win >= 3

    def sample(gain=1.0):
        e = _ar1(rng, n, 0.8)
        return {"y": e + 0.3 * rng.standard_normal(n), "u": gain * (-2.0 * e + 0.5 * rng.standard_normal(n))}
    chis = []
    for gain in (1.0, 1.3):
        rs = []
        for _ in range(40):
            runs = [sample() for _ in range(8)]
            mean = {v: np.mean([r[v] for r in runs], axis=0) for v in ("y", "u")}
            d = features(lay, sample(gain))
            fm = features(lay, mean, runs=runs)
            W = Whitener.build(lay, d, fm)
            g = W.groups()
            rs.append(W.residual(d, fm)[g["band"]])
        rs = np.array(rs)
        chis.append(np.mean(rs ** 2))
    assert 0.75 < chis[0] < 1.3, chis
    assert chis[1] > 3.0, chis


def test_a_layout_reads_bands_and_device_lines_together():
    """A device with views compared in bands and views compared at its own lines gets both."""
    fr = make_frame(FS, 0, 8192, {}, None, None)
    lay = make_layout(fr, {}, views=("y", "u"), band_views=("y",), exclude_hz=(123.4,), dl_views=("u",),
                      dl_floor=(0.0,))
    assert lay.bands and lay.band_views == ("y",)
    assert lay.dl_views == ("u",) and lay.dl_hz == (123.4,)


def test_windows_see_a_drift_that_the_dc_does_not():
    """A ramp of zero mean in the data: the window features' whitened chi-square is far above its
    entries, while noise alone gives about one per entry."""
    rng = np.random.default_rng(9)
    n = 8192
    fr = make_frame(FS, 0, n, {}, None, None)
    lay = make_layout(fr, {}, views=("y",))
    W_ = lay.n_win
    assert W_ >= 8

    def chi(drift):
        out = []
        for _ in range(30):
            t = np.arange(n) / FS
            d = features(lay, {"y": _ar1(rng, n, 0.5) + drift * (t - t.mean())})
            m = features(lay, {"y": _ar1(rng, n, 0.5)})
            W = Whitener.build(lay, d, m)
            out.append(np.mean(W.residual(d, m)[W.groups()["win"]] ** 2))
        return np.mean(out)
    assert 0.7 < chi(0.0) < 1.4
    assert chi(0.5) > 5.0


def test_replicate_factors_of_windows_and_bands():
    """Replicates whose window means scatter 4 times the variance each one's own noise estimate
    gives: factor about 4 for the windows; bands at their own noise: about 1."""
    rng = np.random.default_rng(2)
    n = 8192
    fr = make_frame(FS, 0, n, {}, None, None)
    lay = make_layout(fr, {}, views=("y",), band_views=("y",))
    fs = []
    for _ in range(12):
        slow = np.repeat(rng.standard_normal(lay.n_win), lay.win_len)
        slow = np.concatenate([slow, np.zeros(n - len(slow))])
        x = rng.standard_normal(n) + slow * math.sqrt(3.0 / lay.win_len)
        fs.append(features(lay, {"y": x}))
    fac = replicate_factors(fs)
    assert len(fac) == 5
    assert 2.5 < fac[2][0] < 6.0, fac
    assert 0.99 < fac[3][0] < 1.6, fac
    f2 = scale_views(fs[0], *fac)
    assert np.allclose(f2.cov_win, fs[0].cov_win * fac[2][0])


# -- the engine on a loop driven by its own noise (no excitation) ------------------------------
def _evidence_drift(ft, alpha, st):
    w = ft.windows.get("u")
    if not w:
        return {"score": 0.0, "log10_p": 0.0, "significant": False, "hints": {}, "details": {}}
    from scipy import stats
    lp = float(stats.chi2.logsf(w["chi2_trend"], w["k"] - 1)) / math.log(10.0)
    sig = lp < math.log10(alpha)
    return {"score": w["chi2_trend"] if sig else 0.0, "log10_p": lp, "significant": sig, "hints": {},
            "details": {"chi2_trend": w["chi2_trend"]}}


DRIFT = SimpleNamespace(
    NAME="drift", REQUIRED=("rate_n_per_s",), OPTIONAL=(), SIGNATURE="a ramp of u over the windows", SEARCHABLE=True,
    NEEDS_HINT=False, validate=lambda p, where: p, evidence=_evidence_drift,
    claim=lambda ft, hints, df, st: ft.windows.get("u", {}).get("chi2_trend", 0.0),
    model=lambda hints, rec, st: EffectModel("drift", ("rate_n_per_s",), np.zeros(1), np.full(1, 0.02),
                                             np.full(1, -5.0), np.full(1, 5.0),
                                             lambda t: [{"name": "drift", "rate_n_per_s": float(t[0])}], {}),
    report=lambda m, th, se, sig: [{"name": "drift", "params": {"rate_n_per_s": float(th[0])},
                                    "uncertainty": {"rate_n_per_s": float(se[0])}}])


class NoiseLoop(Device):
    """A first-order plant under PI control held at a constant reference, driven by a random
    force; its output spectrum depends on the plant gain (the loop's bandwidth)."""

    name = "noiseloop"
    channels = ("y", "u")
    view_names = ("y", "u")
    cost_views = ("y", "u")
    units = {"y": "m", "u": "A"}
    features = FeatureSpec(axis_views={"r": ("y", "u")}, band_views=("y", "u"))

    @property
    def effects(self):
        return {"drift": DRIFT}

    def validate(self, arrays, source):
        pass

    def record(self, arrays, meta, cfg, source):
        n = len(arrays["y"])
        r = np.zeros(n)
        return Record(self, FS, {c: np.asarray(arrays[c], float) for c in self.channels}, {"r": r},
                      {"kind": "none"}, (), {}, None, None, "levitated", None, usable=((0, n),))

    def priors(self, cfg):
        return {"plant.b_gain": 0.2}

    def floors(self, settings):
        return {"y": 1e-9, "u": 1e-9}

    def replay(self, cfg, record, effects, n, seed):
        rng = np.random.default_rng(1000 + (0 if seed is None else seed))
        a, b = cfg["plant"]["a"], cfg["plant"]["b_gain"]
        rate = sum(e["rate_n_per_s"] for e in effects if e["name"] == "drift")
        w = rng.standard_normal(n)
        v = 1e-5 * rng.standard_normal(n)
        y, u = np.zeros(n), np.zeros(n)
        x, integ = 0.0, 0.0
        for k in range(n):
            ym = x + v[k]
            integ += 0.2 * (-ym) * 1e3
            u[k] = 800.0 * (-ym) + integ
            y[k] = ym
            d = rate * k / FS + 0.2 * w[k]
            x = a * x + (1 - a) * b * (u[k] + d) * 1e-3
        return Replay({"y": y, "u": u})


CFG = {"plant": {"a": 0.98, "b_gain": 1.0},
       "closeloop": {"replay_seeds": 6, "discard_s": 0.2, "max_effects": 1, "line_search_max_hz": 400.0,
                     "calibration_step_rel": 0.2}}


def _noise_data(b, effects, seed=77, n=12000):
    dev = NoiseLoop()
    cfg = {"plant": {"a": 0.98, "b_gain": b}}
    rec = dev.record({"y": np.zeros(n), "u": np.zeros(n)}, {}, cfg, "noise")
    ch = dev.replay(cfg, rec, effects, n, seed).channels
    return {"fs_hz": FS, "t": np.arange(n) / FS, **ch}


@pytest.mark.parametrize("rate", [0.0, 0.4])
def test_the_engine_on_a_loop_without_excitation(rate):
    """No excitation at all: the plant gain 25 % off is calibrated from the bands (within 3
    standard errors, identified), and a slow drift of the force is found from the windows when
    present, nothing otherwise."""
    from ssamb.closeloop import analyse

    eff = [{"name": "drift", "rate_n_per_s": rate}] if rate else []
    rep = analyse(_noise_data(1.25, eff), {}, CFG, device=NoiseLoop())
    p = rep["parameters"].get("plant.b_gain")
    assert p is not None, rep["not_identifiable"]
    assert abs(p["value"] - 1.25) < 3 * p["se"], p
    assert p["se"] < 0.2 / 3
    names = [e["name"] for e in rep["effects"]]
    assert names == (["drift"] if rate else []), rep["summary"]
    if rate:
        f = rep["effects"][0]
        assert abs(f["params"]["rate_n_per_s"] - rate) < 3 * f["uncertainty"]["rate_n_per_s"] + 0.02


def test_device_lines_of_a_record_without_period():
    """Lines the device makes (at frequencies off the DFT grid) read by a least-squares fit in a
    Hann frame: about one chi-square unit per line under noise alone, far more with a sinusoid of
    a tenth of the noise's rms at one of them."""
    from ssamb.closeloop.residual import _device_lines, _line_floor
    from ssamb.closeloop.spectra import dft, noise_floor

    rng = np.random.default_rng(4)
    n = 20000
    fr = make_frame(FS, 0, n, {}, None, None)
    lines = (123.4567, 234.5678, 345.6789)
    t = np.arange(n) / FS
    chis = {}
    for amp in (0.0, 0.1):
        vals = []
        for _ in range(40):
            e = rng.standard_normal(n) + amp * np.cos(2 * np.pi * lines[1] * t + 0.3)
            X = {"c": dft(fr, e)}
            Sl = {"c": _line_floor(fr, noise_floor(fr, X["c"]), 0.0)}
            vals.append(_device_lines(fr, X, Sl, lines, ("c",), {"c": e}, {"c": 0.0})["c"]["chi2"])
        chis[amp] = np.mean(vals)
    assert 2.2 < chis[0.0] < 4.0, chis
    assert chis[0.1] > 20.0, chis


def test_report_says_when_the_misfit_stays_far_above_the_noise_and_how_the_optimum_is_known():
    """The notes name the views whose held-out chi-square per entry stays above twice the noise's,
    and an unconverged joint refit; a model at the noise gets no note."""
    from ssamb.closeloop.report import _misfit_notes
    from ssamb.closeloop.search import optimum_of

    mis = {"ratio": 5.0, "views": {"y": {"ratio": 9.0}, "u": {"ratio": 1.1}}}
    notes = _misfit_notes(mis, {"converged": True})
    assert len(notes) == 1 and "5 times the noise" in notes[0] and "y 9" in notes[0] and "u 1.1" not in notes[0]
    assert _misfit_notes({"ratio": 1.05, "views": {"y": {"ratio": 1.1}}}, {"converged": True}) == []
    fit = SimpleNamespace(converged=False, iterations=12, evaluations=300,
                          history=[{"step_norm": 3.0}, {"step_norm": 1.7}, {"noise_factors": []}])
    opt = optimum_of(fit, 1.0)
    assert not opt["converged"] and opt["last_step_posterior_sd"] == 1.7
    assert "did NOT converge" in _misfit_notes({}, opt)[0]


def test_a_single_period_held_out_part_reads_its_dc_noise_from_the_fitting_part():
    """A periodic record (5 Hz multisine, 40 periods of fitting part, one held out) with noise a
    loop with integral action leaves: small at DC, large above (first-order high-pass at 20 Hz
    plus a little white noise). The held-out part is too short to be periodic; its own Welch
    estimate reads the DC noise at its lowest bins, far above DC, and the whitened DC difference
    of data and model then scatters far below one. With the fitting part's low-frequency noise
    (:func:`ssamb.closeloop.features.low_frequency_from`) it scatters about one, and a small
    offset shows."""
    from ssamb.closeloop.features import low_frequency_from

    rng = np.random.default_rng(17)
    fs, n_p = 2000.0, 400
    P = 41
    n = n_p * P
    t = np.arange(n) / fs
    s = sum(np.sin(2 * np.pi * f * t + k) for k, f in enumerate((5.0, 10.0, 15.0, 20.0, 25.0)))
    fr_fit = make_frame(fs, 0, n_p * (P - 1), {"y": s}, n_p, np.array([5.0, 10.0, 15.0, 20.0, 25.0]))
    fr_hold = make_frame(fs, n_p * (P - 1), n_p, {"y": s}, n_p, np.array([5.0, 10.0, 15.0, 20.0, 25.0]))
    assert fr_fit.periodic and not fr_hold.periodic
    lay_f = make_layout(fr_fit, {"y": s}, views=("y",))
    lay_h = make_layout(fr_hold, {"y": s}, views=("y",))
    b, a = signal.butter(1, 20.0, "highpass", fs=fs)

    def sample(offset=0.0):
        return {"y": s + signal.lfilter(b, a, rng.standard_normal(n)) + 0.05 * rng.standard_normal(n) + offset}

    def dc(offset, shared):
        out = []
        for _ in range(200):
            d, m = sample(offset), sample()
            fd, fm = features(lay_h, d), features(lay_h, m)
            if shared:
                fd = low_frequency_from(fd, lay_h, features(lay_f, d), fr_fit.n)
                fm = low_frequency_from(fm, lay_h, features(lay_f, m), fr_fit.n)
            W = Whitener.build(lay_h, fd, fm)
            out.append(W.residual(fd, fm)[W.groups()["dc"]][0])
        return np.array(out)
    own, shared = dc(0.0, False), dc(0.0, True)
    assert np.var(own) < 0.2, np.var(own)
    assert 0.7 < np.var(shared) < 1.4, np.var(shared)
    # an offset of two standard deviations of the held-out DC difference: seen with the shared
    # estimate (mean whitened value near 2), barely with the part's own
    sd_sum = np.sqrt(features(lay_f, sample()).cov_dc[0, 0] / fr_fit.n * n_p * 2)
    off = 2.0 * sd_sum / n_p
    assert np.mean(dc(off, True)) == pytest.approx(2.0, abs=0.35)
    assert abs(np.mean(dc(off, False))) < 1.0


def test_a_device_line_whose_replays_spread_has_its_own_noise_factor():
    """:meth:`ssamb.closeloop.comparison.Comparison.noise_factors` (uncached): a view's entries share the
    median replicate variance (times 1 + 1/m, over the median of chi-square over its degrees of
    freedom); a device line (its real and imaginary entries, not adjacent in the vector) whose
    replicates spread 25 times more keeps its own variance, one that spreads less keeps the
    view's."""
    from types import SimpleNamespace

    from ssamb.closeloop.comparison import Comparison

    m = 8
    z = np.arange(m, dtype=float)
    z = (z - z.mean()) / z.std(ddof=1)                  # unit sample variance exactly
    sd = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 5.0, 1.0, 5.0])
    labels = [("lines", "u_y", 10.0 * k) for k in range(1, 5)]
    labels += [("dl", "u_y", 6700.0), ("dl", "u_y", 39900.0)] * 2     # real parts, then imaginary parts
    runs = [sd * zk for zk in z]
    part = SimpleNamespace(whitener=SimpleNamespace(labels=labels))
    fake = SimpleNamespace(seeds=range(m), replay=SimpleNamespace(runs=lambda e, n, o, s: runs),
                           residual=lambda p, r: r, groups=lambda p: [np.arange(8)])
    out = Comparison._noise_factors(fake, part, None, ())
    shared = (1 + 1 / m) / (1 - 2 / (9 * (m - 1))) ** 3
    assert out[[0, 1, 2, 3, 4, 6]] == pytest.approx(np.full(6, shared))
    assert out[[5, 7]] == pytest.approx(np.full(2, 25.0 * (1 + 1 / m)))


# -- the unbalance's evidence: a line in both axes in quadrature, or in one axis beside a noisy other

_WHIRL = SimpleNamespace(whirl_phase_min_deg=10.0, whirl_ratio_max=5.0)


def _line_ft(ax: complex, ay: complex, se_x: float, se_y: float, f_hz: float = 170.0):
    ln = {"f_hz": f_hz, "f_se_hz": 0.01, "phasor": {"d_x": ax, "d_y": ay}, "se": {"d_x": se_x, "d_y": se_y},
          "chi2": {"d_x": abs(ax) ** 2 / se_x ** 2, "d_y": abs(ay) ** 2 / se_y ** 2}}
    return SimpleNamespace(lines=[ln], frame=SimpleNamespace(df_hz=1.25))


def test_whirl_misfit_of_a_quiet_axis_is_the_smallest_allowed_ratio():
    """y = 0 beside a line in x: the closest allowed whirl has |y/x| = 1/5, so the misfit is
    (|x| / 5)^2 / se_y^2; a y lagging x by 90 degrees at any allowed ratio fits exactly."""
    from ssamb.sim.effects.unbalance import whirl_misfit

    assert whirl_misfit(2.0, 0j, 0.01, True, _WHIRL) == pytest.approx((2.0 / 5.0) ** 2 / 0.01 ** 2, rel=1e-9)
    assert whirl_misfit(2.0, -3j, 0.01, True, _WHIRL) == pytest.approx(0.0, abs=1e-9)
    # the strong axis y: x = y / rho, with |rho| up to 5 (x at least a fifth of y)
    assert whirl_misfit(2.0, 0j, 0.01, False, _WHIRL) == pytest.approx((2.0 / 5.0) ** 2 / 0.01 ** 2, rel=1e-9)


@pytest.mark.parametrize("phase", np.linspace(-math.pi, math.pi, 7))
def test_whirl_misfit_does_not_depend_on_the_time_origin(phase):
    """Rotating both phasors by one phase (another start of the record) leaves the misfit."""
    from ssamb.sim.effects.unbalance import whirl_misfit

    rng = np.random.default_rng(11)
    for _ in range(20):
        a, b = complex(*rng.standard_normal(2)), complex(*rng.standard_normal(2))
        se = float(rng.uniform(0.05, 2.0))
        r = complex(math.cos(phase), math.sin(phase))
        for strong_is_x in (True, False):
            assert whirl_misfit(a * r, b * r, se, strong_is_x, _WHIRL) == pytest.approx(
                whirl_misfit(a, b, se, strong_is_x, _WHIRL), rel=1e-9, abs=1e-12)


def test_unbalance_evidence_from_one_axis_when_the_other_is_noisy():
    """A line 37 times its noise in x and, in y, 0.85 of it lagging by 131 degrees but within a
    noise as large (chi-square 1.2): evidence, the speed hinted at the line."""
    from ssamb.sim.effects.unbalance import evidence

    ax = 1.0 + 0j
    ay = 0.85 * complex(math.cos(math.radians(-131)), math.sin(math.radians(-131)))
    ev = evidence(_line_ft(ax, ay, se_x=ax.real / 37.0, se_y=abs(ay) / 1.1), 0.01, _WHIRL)
    assert ev["significant"] and ev["hints"]["speed_hz"] == 170.0
    assert ev["details"]["lines"][0]["one_axis"] == "x"


def test_no_unbalance_evidence_from_one_axis_when_the_other_is_quiet():
    """The same x line, y measured to a hundredth of it and empty: not a rotating force."""
    from ssamb.sim.effects.unbalance import evidence

    ev = evidence(_line_ft(1.0 + 0j, 0j, se_x=1 / 37.0, se_y=0.01), 0.01, _WHIRL)
    assert not ev["significant"] and not ev["hints"]
    assert ev["details"]["lines"][0]["whirl_misfit_chi2"] > 100


def test_unbalance_evidence_needs_quadrature_when_both_axes_show_the_line():
    """Both axes 30 times their noise: y lagging x by 90 degrees is a whirl, y in phase is not."""
    from ssamb.sim.effects.unbalance import evidence

    assert evidence(_line_ft(1.0 + 0j, -1j, 1 / 30, 1 / 30), 0.01, _WHIRL)["significant"]
    assert not evidence(_line_ft(1.0 + 0j, 1.0 + 0j, 1 / 30, 1 / 30), 0.01, _WHIRL)["significant"]


def test_whirl_misfit_is_the_minimum_over_the_sector():
    """Against a dense grid of the allowed ratios: never above the grid's minimum, and within
    its resolution of it."""
    from ssamb.sim.effects.unbalance import whirl_misfit

    rng = np.random.default_rng(5)
    ang = np.radians(np.linspace(-170.0, -10.0, 1601))
    rho = (np.geomspace(0.2, 5.0, 801)[:, None] * np.exp(1j * ang)[None, :]).ravel()
    for _ in range(30):
        a, b = complex(*rng.standard_normal(2)), complex(*(3 * rng.standard_normal(2)))
        for strong_is_x, pred in ((True, rho * a), (False, a / rho)):
            grid = float(np.min(np.abs(b - pred)) ** 2)
            got = whirl_misfit(a, b, 1.0, strong_is_x, _WHIRL)
            assert got <= grid + 1e-12
            assert math.sqrt(grid) - math.sqrt(got) <= 0.01 * (abs(a) * 5 + abs(b))


@pytest.mark.parametrize("noise", ["white", "white, periodic frame", "a stronger line 2.6 bins away",
                                   "a random walk"])
def test_a_lines_frequency_scatters_as_its_standard_error_says(noise):
    """The frequency ``fit_line`` estimates (the unbalance's spin speed) scatters over 200 noise
    draws as its own standard error ``f_se_hz`` says: within 20 % in white noise, where the
    taper of a non-periodic frame costs at most 1.7 times the Cramer-Rao bound, a periodic frame
    (no taper) 1.4 times (its projection takes one of five periods' worth of information, the
    local noise estimate a little more: the louder of two sides of about three off-grid bins
    each, up to a quarter above the noise); never more than 20 % above it beside a line four times
    stronger 2.6 resolutions away or under a random walk's low-frequency power; unbiased in every
    case within three standard errors of the mean."""
    from ssamb.closeloop.spectra import crb_frequency_se, fit_line

    rng = np.random.default_rng(8)
    n, f0, amp, sig = 2000, 129.37, 1.0, 2.0
    if noise.endswith("periodic frame"):
        per = 400                                # 5 periods of 0.4 s, a multisine at 10-50 Hz
        tt = np.arange(n) / FS
        s = sum(np.cos(2 * np.pi * f * tt + f) for f in (10.0, 20.0, 30.0, 40.0, 50.0))
        fr = make_frame(FS, 0, n, {"y": s}, per, np.array([10.0, 20.0, 30.0, 40.0, 50.0]))
        assert fr.periodic
    else:
        fr = make_frame(FS, 0, n, {}, None, None)
    t = fr.t_s
    est, se, crb = [], [], []
    for _ in range(200):
        x = amp * np.cos(2 * np.pi * f0 * t + 0.7) + sig * rng.standard_normal(n)
        if noise.startswith("a stronger"):
            x += 4 * amp * np.cos(2 * np.pi * (f0 - 2.6 * fr.df_hz) * t + rng.uniform(0, 2 * np.pi))
        elif noise == "a random walk":
            x += 30 * sig * np.cumsum(rng.standard_normal(n)) / math.sqrt(n)
        ln = fit_line(fr, {"v": x}, {"v": sig}, f0)
        est.append(ln["f_hz"])
        se.append(ln["f_se_hz"])
        crb.append(crb_frequency_se(fr.df_hz, amp ** 2 / ln["se"]["v"] ** 2))
    spread, pred = float(np.std(est)), float(np.median(se))
    assert abs(np.mean(est) - f0) < 3 * spread / math.sqrt(200)
    if noise.startswith("white"):
        assert (0.75 if fr.periodic else 0.8) * pred < spread < 1.2 * pred, (spread, pred)
        assert pred < (1.4 if fr.periodic else 1.7) * float(np.median(crb))
    else:
        assert spread < 1.2 * pred, (spread, pred)


@pytest.mark.parametrize("f0", [36.2, 37.3])
def test_a_line_clear_in_one_view_takes_its_frequency_from_that_view(f0):
    """:func:`ssamb.closeloop.residual._find_lines` on a periodic frame (untapered, period 0.4 s): a
    line 50 times its noise in one view and at its noise in another, whose noise rises towards low
    frequencies (a random walk: the self-sensed axis). Over 40 noise draws the frequency scatters
    within its standard error (between 0.7 and 1.2 of it), unbiased within three standard errors
    of the mean, and the standard error is within 1.3 times the clear view's Cramer-Rao bound
    halfway between two harmonics of the period (36.2 Hz); beside one (37.3 Hz, 0.08 cycles per
    period off) the projection takes more of the line and the bound does not hold, but the
    scatter still does. The floor the line is detected on holds the line's own leakage, a thousand
    times the clear view's noise there: weighted by it the clear view would count for less than
    the noisy one."""
    from ssamb.closeloop.residual import _find_lines
    from ssamb.closeloop.spectra import crb_frequency_se, dft, noise_floor

    rng = np.random.default_rng(11)
    n, sig, per = 4000, 0.02, 400                    # 10 periods of a multisine at 10-50 Hz
    tt = np.arange(n) / FS
    fr = make_frame(FS, 0, n, {"y": sum(np.cos(2 * np.pi * f * tt + f) for f in (10.0, 20.0, 30.0, 40.0, 50.0))},
                    per, np.array([10.0, 20.0, 30.0, 40.0, 50.0]))
    t = fr.t_s
    est, se = [], []
    for _ in range(40):
        ph = rng.uniform(0, 2 * np.pi)
        res = {"a": np.cos(2 * np.pi * f0 * t + ph) + sig * rng.standard_normal(n),
               "b": np.sin(2 * np.pi * f0 * t + ph) + rng.standard_normal(n)
               + 0.3 * np.cumsum(rng.standard_normal(n))}
        X = {v: dft(fr, x) for v, x in res.items()}
        S = {v: noise_floor(fr, X[v]) for v in res}
        found, _ = _find_lines(fr, res, X, S, {"a": 0.0, "b": 0.0},
                               SimpleNamespace(line_search_max_hz=200.0, alpha_evidence=1e-3),
                               SimpleNamespace(view_names=["a", "b"]))
        ln = min(found, key=lambda ln: abs(ln["f_hz"] - f0))
        est.append(ln["f_hz"])
        se.append(ln["f_se_hz"])
    spread, pred = float(np.std(est)), float(np.median(se))
    assert 0.7 * pred < spread < 1.2 * pred, (spread, pred)
    assert abs(np.mean(est) - f0) < 3 * spread / math.sqrt(len(est))
    if f0 == 36.2:
        assert pred < 1.3 * crb_frequency_se(fr.df_hz, n / (2 * sig ** 2)), pred


@pytest.mark.parametrize("periodic, delayed", [(False, False), (True, False), (False, True)])
def test_views_of_one_noise_count_once_in_a_lines_frequency_error(periodic, delayed):
    """:func:`ssamb.closeloop.spectra.fit_line` on three views of one loop: the same line and the
    same noise, scaled by 1, 2 and -0.5 (a position, its error doubled, a controller output), as
    the views of one axis carry the loop's noise; or (``delayed``) the third view the first two
    samples later, a phase of 1.6 rad at the line, so that the views' coherence is complex (with
    its conjugate the shared noise would enter with the cosine of twice that phase, -0.99).
    Over 200 draws the frequency scatters as its standard error says (between 0.8 and 1.2 of it),
    where views taken as independent would report the error of three separate measurements, a
    square root of three too small."""
    from ssamb.closeloop.spectra import fit_line

    rng = np.random.default_rng(12)
    n, f0, amp, sig = 2000, 129.37, 1.0, 2.0
    if periodic:
        tt = np.arange(n) / FS
        s = sum(np.cos(2 * np.pi * f * tt + f) for f in (10.0, 20.0, 30.0, 40.0, 50.0))
        fr = make_frame(FS, 0, n, {"y": s}, 400, np.array([10.0, 20.0, 30.0, 40.0, 50.0]))
    else:
        fr = make_frame(FS, 0, n, {}, None, None)
    est, se = [], []
    for _ in range(200):
        tt = np.arange(-2, n) / FS
        xx = amp * np.cos(2 * np.pi * f0 * tt + 0.7) + sig * rng.standard_normal(n + 2)
        x = xx[2:]
        third = xx[:-2] if delayed else -0.5 * x
        sigmas = {"a": sig, "b": 2 * sig, "c": sig if delayed else 0.5 * sig}
        ln = fit_line(fr, {"a": x, "b": 2 * x, "c": third}, sigmas, f0)
        est.append(ln["f_hz"])
        se.append(ln["f_se_hz"])
    spread, pred = float(np.std(est)), float(np.median(se))
    assert 0.8 * pred < spread < 1.2 * pred, (spread, pred)


def test_the_unbalance_fits_its_force_at_the_lines_speed():
    """The unbalance model's free parameters are the force's two components; the speed is the
    line's, reported with the line's standard error."""
    from ssamb.sim.effects import unbalance

    m = unbalance.model({"speed_hz": 129.22, "speed_se_hz": 0.0025}, None, _WHIRL)
    assert m.params == ("me_cos_kgm", "me_sin_kgm")
    built = m.build(np.array([3e-6, 4e-6]))[0]
    assert built["speed_hz"] == 129.22 and built["mass_ecc_kgm"] == pytest.approx(5e-6)
    rep = unbalance.report(m, np.array([3e-6, 4e-6]), np.array([1e-7, 1e-7]), True)[0]
    assert rep["params"]["speed_hz"] == 129.22 and rep["uncertainty"]["speed_hz"] == 0.0025
    assert rep["force_n"] == pytest.approx(5e-6 * (2 * math.pi * 129.22) ** 2)


def test_an_unbalances_neighbours_keep_its_force_where_the_fitting_part_pins_it():
    """The family the search moves an unbalance's speed along: whole standard errors of the line's
    frequency, the force's phase at the fitting part's centre unchanged (its amplitude follows the
    speed squared), and no speed at or below zero."""
    from ssamb.sim.effects import unbalance

    m = unbalance.model({"speed_hz": 40.0, "speed_se_hz": 0.05}, None, None)
    me, ph, t_c = 2e-5, 0.7, 0.25
    theta = np.array([me * math.cos(ph), me * math.sin(ph)])
    fam = unbalance.neighbours(m, theta, t_c, [-2.0, 1.0])
    assert [m2.fixed["speed_hz"] for m2, _ in fam] == pytest.approx([39.9, 40.05])
    for m2, th2 in fam:
        e = m2.build(th2)[0]
        assert e["mass_ecc_kgm"] == pytest.approx(me)
        d = (2 * math.pi * e["speed_hz"] * t_c + e["phase_rad"]) - (2 * math.pi * 40.0 * t_c + ph)
        assert math.remainder(d, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert unbalance.neighbours(m, theta, t_c, [-1000.0]) == []
    assert unbalance.neighbours(unbalance.model({"speed_hz": 40.0}, None, None), theta, t_c, [1.0]) == []


def _started_line(t, f_hz, rng=None, sigma=0.0, phase=0.4, t_ref=0.4):
    """A line at ``f_hz`` whose amplitude and phase settle from a start-up transient (both decay
    with 0.1 s), the phase ``phase`` at ``t_ref``, with white noise ``sigma``."""
    env, ph = 1 + 0.5 * np.exp(-t / 0.1), 0.3 * np.exp(-t / 0.1)
    x = env * np.cos(2 * np.pi * f_hz * (t - t_ref) + ph + phase)
    return x if rng is None else x + sigma * rng.standard_normal(len(t))


def _drift_scatter(fr, t, f, d, sigma, draws, misfit=None, seed=7):
    """z-scores of :func:`line_drift` over noise draws: the data's line ``d`` Hz faster than the
    model's, both with the same start-up transient, two views of one noise (the second scaled
    by 3), and ``misfit`` (the model's error of an excitation) in the residual."""
    from ssamb.closeloop.spectra import line_drift

    t_c = (fr.i0 + fr.n / 2) / fr.fs_hz
    line = _started_line(t, f, t_ref=t_c)
    rng = np.random.default_rng(seed)
    z = []
    for _ in range(draws):
        r = _started_line(t, f + d, rng, sigma, t_ref=t_c) - line + (0.0 if misfit is None else misfit)
        out = line_drift(fr, {"a": r, "b": 3 * r}, {"a": line, "b": 3 * line}, f)
        z.append((out["delta_hz"] - d) / out["se_hz"])
    return np.array(z)


def test_a_speed_error_is_read_against_the_models_own_line_through_a_shared_transient():
    """The data hold the model's line 10 mHz faster, and both start with the same transient in
    amplitude and phase: the drift of the data's phase against the model's line is unbiased and
    its standard error is the scatter's (two views of one noise counted once); a sinusoid fitted
    to the data alone reads the transient as a frequency."""
    from ssamb.closeloop.spectra import fit_line

    fs, f, d, sigma = 10_000.0, 149.6, 0.01, 0.3
    t = np.arange(8000) / fs
    fr = make_frame(fs, 200, 6000, {}, None, None)          # from 20 ms: the transient in the frame
    z = _drift_scatter(fr, t, f, d, sigma, 150)
    assert abs(z.mean()) < 0.3 and 0.8 < z.std() < 1.25
    assert 0.9 <= np.mean(np.abs(z) < 2) <= 0.99
    rng = np.random.default_rng(8)
    z_line = []
    for _ in range(12):
        data = _started_line(t, f + d, rng, sigma, t_ref=0.4)[fr.i0:fr.i0 + fr.n]
        ln = fit_line(fr, {"a": data}, {"a": sigma}, f + d)
        z_line.append((ln["f_hz"] - f - d) / ln["f_se_hz"])
    assert np.mean(z_line) < -2.5


def test_a_speed_error_beside_an_excited_line_in_two_periods():
    """A periodic frame of two 0.2 s periods, the line at 58.3 Hz between the multisine's excited
    55 and 60 Hz with the model 2 % off there: removing the synchronous part (the misfit) also
    changes an off-grid line, which the regressors carry, so the drift stays unbiased."""
    fs, f, d, sigma = 5_000.0, 58.3, 0.02, 0.3
    n_per = 1000
    t = np.arange(4 * n_per) / fs
    exc = sum(np.cos(2 * np.pi * fk * t + fk) for fk in range(10, 65, 5))
    fr = make_frame(fs, n_per, 2 * n_per, {"x": exc}, n_per, np.arange(10.0, 65.0, 5.0))
    misfit = 0.02 * sum(20 * np.cos(2 * np.pi * fk * t + 0.3 * fk) for fk in (55.0, 60.0))
    z = _drift_scatter(fr, t, f, d, sigma, 150, misfit=misfit, seed=9)
    assert abs(z.mean()) < 0.3 and 0.8 < z.std() < 1.25


def test_a_line_drift_needs_the_line():
    """A model without the line in any view gives no drift; a clean line gives none beyond its
    error."""
    from ssamb.closeloop.spectra import line_drift

    fs = 10_000.0
    t = np.arange(8000) / fs
    fr = make_frame(fs, 1000, 6000, {}, None, None)
    rng = np.random.default_rng(3)
    assert line_drift(fr, {"a": rng.standard_normal(8000)}, {"a": np.zeros(8000)}, 149.6) is None
    line = _started_line(t, 149.6)
    r = line_drift(fr, {"a": 1e-3 * rng.standard_normal(8000)}, {"a": line}, 149.6)
    assert abs(r["delta_hz"]) < 3 * r["se_hz"] and r["se_hz"] < 1e-4


@pytest.mark.parametrize("centre, expected", [(0.3, 0.3), (-0.7, -0.7), (1.7, 1.7), (2.5, None)])
def test_the_speed_search_takes_the_vertex_of_a_parabola_through_its_costs(centre, expected):
    """The vertex of a cost quadratic in the step is found exactly within the steps scored; one
    beyond them, or a cost without a minimum, gives none."""
    from ssamb.closeloop.speeds import parabola_vertex

    steps = (-2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0)
    v = parabola_vertex({k: (100.0 + 7.0 * (k - centre) ** 2, None) for k in steps})
    assert v == (pytest.approx(expected, abs=1e-3) if expected is not None else None)
    assert parabola_vertex({k: (100.0 - k * k, None) for k in steps}) is None


@pytest.mark.parametrize("centre", [-3.3, -0.7, 0.2, 5.1])
def test_the_speed_profile_is_bracketed_then_refined(centre):
    """A profile sharper than a parabola (a sinc's loss grows like the fourth power far out)
    whose least point lies beyond the first three steps is bracketed by doubling steps and its
    least point found within 0.1 steps, in at most a dozen points."""
    from ssamb.closeloop.speeds import _profile_search

    prof = {}

    def at(k):
        k = round(float(k), 3)
        prof.setdefault(k, {"cost": 500.0 + 300.0 * (k - centre) ** 2 + 40.0 * (k - centre) ** 4})
        return prof[k]
    for k in (-1.0, 0.0, 1.0):
        at(k)
    best = _profile_search(prof, at)
    assert abs(best - centre) < 0.1 and len(prof) <= 12


def test_an_unbalances_phase_error_carries_its_speed_error_to_the_records_start():
    """The data pin the force's phase at the fitting part's centre t; the phase is reported at
    the record's start, so a speed error sigma_f adds 2 pi t sigma_f to it (0.3 s, 2 mHz: 3.77
    mrad beside the amplitude's 20 mrad), and nothing where no centre is named."""
    from ssamb.sim.effects import unbalance

    m = unbalance.model({"speed_hz": 50.0, "speed_se_hz": 0.002}, None, _WHIRL)
    theta, se = np.array([3e-6, 4e-6]), np.array([1e-7, 1e-7])
    assert unbalance.report(m, theta, se, True)[0]["uncertainty"]["phase_rad"] == pytest.approx(0.02)
    m.fixed["phase_t_s"] = 0.3
    got = unbalance.report(m, theta, se, True)[0]["uncertainty"]["phase_rad"]
    assert got == pytest.approx(math.hypot(0.02, 2 * math.pi * 0.3 * 0.002))
    # moving the speed by one error moves the phase at t = 0 by that much, the phase at t unchanged
    (m2, th2), = unbalance.neighbours(m, theta, 0.3, [1.0])
    d0 = math.remainder(m2.build(th2)[0]["phase_rad"] - math.atan2(4e-6, 3e-6), 2 * math.pi)
    assert abs(d0) == pytest.approx(2 * math.pi * 0.3 * 0.002)


class _LineComparison:
    """A comparison whose model is a fixed signal plus an unbalance's line in one channel, and
    whose residual is the samples' difference from the data in units of their noise: the
    least-squares problem :func:`ssamb.closeloop.speeds.profile_point` solves, in the open."""

    def __init__(self, t, data, sigma):
        from types import SimpleNamespace
        self.t, self.data, self.sigma = t, data, sigma
        self.device = SimpleNamespace(channels=("a",))
        self.fit = None
        self.replays = 0

    def prediction(self, overrides, effects):
        self.replays += 1
        x = np.zeros_like(self.t)
        for e in effects:
            w = 2 * math.pi * e["speed_hz"]
            x = x + e["mass_ecc_kgm"] * w * w * np.cos(w * self.t + e["phase_rad"])
        return {"a": x, "delevitated_share": 0.0}

    def residual(self, part, ch):
        return (ch["a"] - self.data) / self.sigma


def test_a_profile_point_solves_the_size_at_its_speed():
    """At the true speed the size parameters come out of a wrong start (half the size, a
    quarter turn off) within three of their standard errors, with one replay per size
    parameter; at a speed off by a third of the record's resolution the cost is higher and the
    size the line leaves is smaller (the sinc loss the joint refit suffers at a wrong speed)."""
    from types import SimpleNamespace

    from ssamb.closeloop.speeds import profile_point
    from ssamb.sim.effects import unbalance

    rng = np.random.default_rng(3)
    t = np.arange(4000) / 5000.0
    f, me, ph, sigma = 70.2, 1.3e-5, 0.9, 0.05
    w = 2 * math.pi * f
    data = me * w * w * np.cos(w * t + ph) + sigma * rng.standard_normal(len(t))
    cmp = _LineComparison(t, data, sigma)
    m = unbalance.model({"speed_hz": f, "speed_se_hz": 0.01}, None, None)
    a = {"model": m, "theta": np.array([0.5 * me * math.cos(ph + 1.5), 0.5 * me * math.sin(ph + 1.5)])}
    out = SimpleNamespace(overrides={}, accepted=[a])
    without = {"a": np.zeros_like(t), "delevitated_share": 0.0}
    pt = profile_point(cmp, out, a, m, a["theta"], without)
    se = sigma * math.sqrt(2 / len(t)) / (w * w)              # per component of the force's phasor
    assert cmp.replays == 2
    assert abs(pt["theta"][0] - me * math.cos(ph)) < 3 * se and abs(pt["theta"][1] - me * math.sin(ph)) < 3 * se
    assert pt["cost"] < 1.2 * len(t)
    off = unbalance.model({"speed_hz": f + 0.4, "speed_se_hz": 0.01}, None, None)
    pt_off = profile_point(cmp, out, a, off, a["theta"], without)
    assert pt_off["cost"] > pt["cost"] + 100 and pt_off["size"] < 0.95 * pt["size"]


def test_an_unbalances_size_error_carries_its_speeds():
    """The size's error is the one at the speed and the profile's slope per error of the speed
    in quadrature; the phase's is not widened by the slope."""
    from ssamb.sim.effects import unbalance

    m = unbalance.model({"speed_hz": 40.0, "speed_se_hz": 0.05}, None, None)
    th, se = np.array([3e-6, 4e-6]), np.array([1e-7, 1e-7])
    plain = unbalance.report(m, th, se, True)[0]["uncertainty"]
    m.fixed["size_se_speed"] = 2.4e-7
    wide = unbalance.report(m, th, se, True)[0]["uncertainty"]
    assert wide["mass_ecc_kgm"] == pytest.approx(math.hypot(1e-7, 2.4e-7))
    assert wide["phase_rad"] == pytest.approx(plain["phase_rad"])
