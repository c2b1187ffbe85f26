"""Figures of the close-the-loop analysis (matplotlib, Agg backend), written as PNG files.

* ``calibration.png``: every calibratable parameter's estimate relative to its nominal value,
  in units of its tolerance, with two standard errors (identified ones coloured, the others
  grey: their estimate is the prior's);
* ``features.png``: the held-out feature residual per view, :math:`\\chi^2/n` (1 is noise) for
  the nominal model, the calibrated one and the final one -- what the tests judge;
* ``residual_time.png``: held-out residual per view, nominal, calibrated and final, with the
  noise level;
* ``residual_spectra.png``: residual spectra, the same three models, with the noise floor;
* ``evidence.png``: the evidence for each library effect in the calibrated model's residual,
  before any fitting (explained chi-square, log scale; significant ones coloured);
* ``sensor_ratio.png``: measured/model ratio of the sensor paths (gain and phase) at the
  excited lines, calibrated and final (when an axis is excited).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["make_figures"]

_MODELS = (("nominal", "tab:red"), ("calibrated", "tab:orange"), ("final", "tab:blue"))
#: display scale of a unit
_SCALES = {"m": (1e6, "um"), "A": (1e3, "mA"), "V": (1.0, "V")}


def _scale(dev, v: str) -> tuple[float, str]:
    u = dev.unit(v)
    return _SCALES.get(u, (1.0, u))


def _envelope(t: np.ndarray, y: np.ndarray, buckets: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y)`` for a line plot of a long record: per bucket of consecutive samples its minimum
    and its maximum, in the order they occur (about ``buckets`` of them, about twice a figure's
    width in pixels: the drawn line covers the same pixels as with every sample, at a fraction of
    the rendering time). A record of at most ``2 * buckets`` samples is returned as it is."""
    y = np.asarray(y)
    n = len(y)
    if n <= 2 * buckets:
        return t, y
    size = -(-n // buckets)
    full = n // size
    starts = np.arange(full + (n % size > 0)) * size
    blocks = y[: full * size].reshape(full, size)
    i_lo, i_hi = starts[:full] + blocks.argmin(axis=1), starts[:full] + blocks.argmax(axis=1)
    if n % size:
        tail = y[full * size:]
        i_lo = np.append(i_lo, full * size + int(tail.argmin()))
        i_hi = np.append(i_hi, full * size + int(tail.argmax()))
    idx = np.column_stack([np.minimum(i_lo, i_hi), np.maximum(i_lo, i_hi)]).ravel()
    return t[idx], y[idx]


def _save(fig, out_dir: Path, name: str, names: list) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(out_dir / name, dpi=90)
    plt.close(fig)
    names.append(name)


def _calibration(rep: dict, out_dir: Path, names: list) -> None:
    import matplotlib.pyplot as plt

    per = rep["calibration"].get("parameters", [])
    if not per:
        return
    fig, ax = plt.subplots(figsize=(8, 0.45 * len(per) + 1.5))
    for i, p in enumerate(per):
        z = p["z_from_nominal"]
        e = 2 * p["se"] / p["tolerance"] if p["tolerance"] else 0.0
        col = "tab:blue" if p["identified"] else "0.7"
        ax.errorbar(z, i, xerr=min(e, 10.0), fmt="o", color=col, capsize=3)
    ax.axvspan(-1, 1, color="0.93", zorder=0, label="tolerance (1 sd)")
    ax.axvline(0, color="k", lw=0.6)
    ax.set_yticks(range(len(per)))
    ax.set_yticklabels([p["key"] for p in per], fontsize=8)
    ax.set_xlim(-6, 6)
    ax.set_xlabel("estimate - nominal, in tolerances (bars: 2 standard errors; grey: not identified)")
    ax.set_title("Calibrated nominal parameters")
    _save(fig, out_dir, "calibration.png", names)


def _features(art: dict, out_dir: Path, names: list) -> None:
    import matplotlib.pyplot as plt

    from .fit import chi2_views

    cmp, search = art["comparison"], art["search"]
    models = {"nominal": search.nominal, "calibrated": search.calibrated, "final": search.final}
    fig, ax = plt.subplots(figsize=(9, 3.8))
    width = 0.27
    for j, (label, col) in enumerate(_MODELS):
        r = cmp.residual(cmp.hold, models[label])
        chi = chi2_views(cmp, cmp.hold, r)
        vs = list(chi)
        ax.bar(np.arange(len(vs)) + (j - 1) * width, [max(chi[v][0] / chi[v][1], 1e-2) for v in vs], width,
               color=col, label=label)
    ax.axhline(1.0, color="k", lw=0.7, ls="--", label="noise")
    ax.set_yscale("log")
    ax.set_xticks(range(len(vs)))
    ax.set_xticklabels(vs)
    ax.set_ylabel("chi2 / n (held-out features)")
    ax.set_title("Held-out feature residual per view: DC, excited lines and lines the excitation lacks")
    ax.legend(fontsize=8)
    _save(fig, out_dir, "features.png", names)


def _time(art: dict, meas: dict, models: dict, sig: dict, out_dir: Path, names: list) -> None:
    import matplotlib.pyplot as plt

    rec, hold = art["record"], art["split"].hold
    dev = rec.device
    t = np.arange(rec.n)[hold] / rec.fs_hz
    vn = dev.view_names
    fig, axs = plt.subplots(len(vn), 1, figsize=(10, 2.0 * len(vn)), sharex=True, squeeze=False)
    axs = axs[:, 0]
    for ax, v in zip(axs, vn):
        k, u = _scale(dev, v)
        for label, col in _MODELS:
            ax.plot(*_envelope(t, k * (meas[v][hold] - models[label][v][hold])), lw=0.5, color=col, label=label)
        if v in sig:
            ax.axhline(2 * k * sig[v], color="k", lw=0.6, ls="--")
            ax.axhline(-2 * k * sig[v], color="k", lw=0.6, ls="--", label="2 x noise")
        ax.set_ylabel(f"{v} ({u})")
    axs[0].legend(loc="upper right", fontsize=7, ncol=4)
    axs[-1].set_xlabel("time (s), held-out part")
    fig.suptitle("Residual (measured - predicted), held-out part")
    _save(fig, out_dir, "residual_time.png", names)


def _spectra(art: dict, meas: dict, models: dict, sig: dict, out_dir: Path, names: list) -> None:
    import matplotlib.pyplot as plt
    from scipy import signal

    rec, hold = art["record"], art["split"].hold
    dev = rec.device
    fs = rec.fs_hz
    nper = int(2 ** max(8, min(15, int(np.log2(max((hold.stop - hold.start) // 4, 256))))))
    nper = min(nper, hold.stop - hold.start)
    vn = dev.view_names
    ncol = 3 if len(vn) > 4 else len(vn)
    nrow = -(-len(vn) // ncol)
    fig, axs = plt.subplots(nrow, ncol, figsize=(4.3 * ncol, 3 * nrow), squeeze=False)
    for ax in axs.ravel()[len(vn):]:
        ax.set_visible(False)
    for ax, v in zip(axs.ravel(), vn):
        k, u = _scale(dev, v)
        for label, col in _MODELS:
            f, p = signal.welch(k * (meas[v][hold] - models[label][v][hold]), fs=fs, nperseg=nper)
            if np.any(p[1:] > 0):
                ax.loglog(f[1:], np.sqrt(np.maximum(p[1:], 1e-300)), lw=0.6, color=col, label=label)
        if v in sig:
            ax.axhline(k * sig[v] * np.sqrt(2 / fs), color="k", lw=0.6, ls="--", label="noise floor")
        ax.set_title(v, fontsize=9)
        ax.set_ylabel(f"{u}/sqrt(Hz)", fontsize=8)
    axs[0, 0].legend(fontsize=7)
    for ax in axs[-1][: len(vn) - (nrow - 1) * ncol]:
        ax.set_xlabel("frequency (Hz)")
    fig.suptitle("Residual amplitude spectral density, held-out part")
    _save(fig, out_dir, "residual_spectra.png", names)


def _evidence(art: dict, out_dir: Path, names: list) -> None:
    import matplotlib.pyplot as plt

    search = art["search"]
    if not search.rounds:
        return
    ev = search.rounds[0]["evidence"]
    labels = list(ev)
    sc = [max(ev[n]["score_chi2"], 1e-1) for n in labels]
    cols = ["tab:green" if ev[n]["significant"] else "0.7" for n in labels]
    found = {a["name"] for a in search.accepted}
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.barh(labels, sc, color=cols)
    ax.set_xscale("log")
    for i, n in enumerate(labels):
        ax.text(sc[i], i, f" log10 p = {ev[n]['log10_p']:.1f}" + ("   FOUND" if n in found else ""), va="center",
                fontsize=7)
    ax.set_xlabel("evidence: residual chi-square the signature explains (calibrated model, before fitting)")
    ax.set_title("Signature evidence per library effect (green: significant)")
    _save(fig, out_dir, "evidence.png", names)


def _ratios(art: dict, meas: dict, models: dict, out_dir: Path, names: list) -> None:
    import matplotlib.pyplot as plt

    from .residual import compute_features

    fig, axs = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    drew = False
    for label, ls in (("calibrated", "-"), ("final", "--")):
        ft = compute_features(art["record"], art["comparison"].fit.frame, meas, models[label], art["settings"])
        for name, r in ft.ratios.items():
            if name not in ("y", "y_plant"):          # the AMB's y paths beside its sensor path
                axs[0].semilogx(r["f_hz"], 20 * np.log10(np.abs(r["R"])), ls, marker=".",
                                label=f"{r['path']} ({label})")
                axs[1].semilogx(r["f_hz"], np.degrees(np.unwrap(np.angle(r["R"]))), ls, marker=".",
                                label=f"{r['path']} ({label})")
                drew = True
    if not drew:
        plt.close(fig)
        return
    axs[0].set_ylabel("gain ratio (dB)")
    axs[1].set_ylabel("phase ratio (deg)")
    axs[1].set_xlabel("frequency (Hz), excited lines")
    axs[0].legend(fontsize=7)
    fig.suptitle("Measured / model ratio of the sensor paths (0 dB, 0 deg when the model is right)")
    _save(fig, out_dir, "sensor_ratio.png", names)


def make_figures(art: dict, rep: dict, out_dir: Path) -> list[str]:
    """Draw the figures into ``out_dir``; return their file names."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    search = art["search"]
    v = art["record"].device.views
    meas = v(art["record"].channels)
    models = {"nominal": v(search.nominal), "calibrated": v(search.calibrated), "final": v(search.final)}
    sig = rep["noise"]["views"]
    names: list = []
    _calibration(rep, out_dir, names)
    _features(art, out_dir, names)
    _time(art, meas, models, sig, out_dir, names)
    _spectra(art, meas, models, sig, out_dir, names)
    _evidence(art, out_dir, names)
    _ratios(art, meas, models, out_dir, names)
    return names


def _holdout_overlay(h: dict, dev, out_dir: Path, names: list) -> None:
    """One held-out recording: every channel measured, nominal and final, over the analysed part."""
    import matplotlib.pyplot as plt

    rec, sl = h["record"], h["range"]
    t = np.arange(rec.n)[sl] / rec.fs_hz
    fig, axs = plt.subplots(len(dev.channels), 1, figsize=(10, 2.3 * len(dev.channels)), sharex=True, squeeze=False)
    for ax, c in zip(axs[:, 0], dev.channels):
        k, u = _scale(dev, c)
        ax.plot(*_envelope(t, k * rec.channels[c][sl]), color="k", lw=0.6, label="measured")
        ax.plot(*_envelope(t, k * h["nominal"][c][sl]), color="tab:red", lw=0.8, label="published parameters")
        ax.plot(*_envelope(t, k * h["final"][c][sl]), color="tab:blue", lw=0.8, label="final model")
        ax.set_ylabel(f"{c} ({u})")
    axs[0, 0].legend(loc="upper right", fontsize=7, ncol=3)
    axs[-1, 0].set_xlabel("time (s)")
    fig.suptitle(f"Held-out recording {h['name']}: measured and replayed (mean of the replays)")
    _save(fig, out_dir, f"holdout_{h['name']}.png", names)


def _holdout_spectra(art: dict, out_dir: Path, names: list) -> None:
    """Residual amplitude spectra of every channel on the held-out recordings, before and after."""
    import matplotlib.pyplot as plt
    from scipy import signal

    dev = art["device"]
    fig, axs = plt.subplots(1, len(dev.channels), figsize=(4.3 * len(dev.channels), 3.4), squeeze=False)
    for ax, c in zip(axs[0], dev.channels):
        k, u = _scale(dev, c)
        for h in art["holdout"]:
            rec, sl = h["record"], h["range"]
            n = sl.stop - sl.start
            nper = int(2 ** max(4, min(12, int(np.log2(max(n // 4, 16))))))
            for label, col, ls in (("nominal", "tab:red", "-"), ("final", "tab:blue", "--")):
                f, p = signal.welch(k * (rec.channels[c][sl] - h[label][c][sl]), fs=rec.fs_hz, nperseg=min(nper, n))
                ax.loglog(f[1:], np.sqrt(np.maximum(p[1:], 1e-300)), ls, lw=0.7, color=col,
                          label=f"{h['name']} {label}")
        ax.set_title(c, fontsize=9)
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel(f"{u}/sqrt(Hz)", fontsize=8)
    axs[0, 0].legend(fontsize=6)
    fig.suptitle("Residual amplitude spectral density on the held-out recordings (red: published, blue: final)")
    _save(fig, out_dir, "holdout_spectra.png", names)


def _agreement(rep: dict, out_dir: Path, names: list) -> None:
    """Per calibrated parameter: each fitting recording's estimate and the combined one, with two
    standard errors, relative to the nominal value."""
    import matplotlib.pyplot as plt

    params = rep.get("parameters", {})
    if not params:
        return
    fig, ax = plt.subplots(figsize=(8, 0.6 * len(params) + 1.6))
    recs = list(rep.get("recordings", {}))
    for i, (key, p) in enumerate(params.items()):
        nom = p["nominal"] or 1.0
        for j, r in enumerate(recs):
            q = p["per_recording"].get(r)
            if q is not None:
                ax.errorbar(100 * (q["value"] / nom - 1), i + 0.12 * (j - len(recs) / 2), xerr=200 * q["se"] / abs(nom),
                            fmt="o", ms=3, capsize=2, color=f"C{j}", label=r if i == 0 else None)
        ax.errorbar(100 * (p["value"] / nom - 1), i + 0.3, xerr=200 * p["se"] / abs(nom), fmt="s", color="k", capsize=3,
                    label="combined" if i == 0 else None)
    ax.axvline(0, color="0.5", lw=0.6)
    ax.set_yticks(range(len(params)))
    ax.set_yticklabels(list(params), fontsize=8)
    ax.set_xlabel("change from the published value (%), bars: 2 standard errors")
    ax.legend(fontsize=7, loc="best")
    ax.set_title("Calibrated parameters per fitting recording and combined")
    _save(fig, out_dir, "agreement.png", names)


def make_recording_figures(art: dict, rep: dict, out_dir: Path) -> list[str]:
    """Figures of an analysis over several recordings (:mod:`ssamb.closeloop.recordings`): the
    held-out recordings overlaid (measured, published-parameter model, final model), their residual
    spectra, and the calibrated parameters per recording; returns the file names."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    names: list = []
    for h in art["holdout"]:
        _holdout_overlay(h, art["device"], out_dir, names)
    if art["holdout"]:
        _holdout_spectra(art, out_dir, names)
    _agreement(rep, out_dir, names)
    return names
