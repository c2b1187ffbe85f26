"""Figures of the close-the-loop analysis (matplotlib, Agg backend), written as PNG files.

* ``residual_time.png``: held-out residual per view, before (nominal model) and after (with the
  effects found), with the noise level;
* ``residual_spectra.png``: residual spectra before and after, with the noise floor;
* ``evidence.png``: the evidence for each library effect before any fitting (explained
  chi-square, log scale; significant ones coloured);
* ``sensor_ratio.png``: measured/model ratio of the sensor paths (gain and phase) at the
  excited lines, before and after;
* ``whiteness.png``: autocorrelation of the held-out residual and its cross-correlation with
  the excitation, before and after, with 99 % bounds for a white residual.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .data import unit_of, views

__all__ = ["make_figures"]

_PLOT_VIEWS = ("x_meas", "y_ss", "y_meas", "d_x", "d_y", "c_x", "c_y", "u_x", "u_y")


def _scale(v: str) -> tuple[float, str]:
    return (1e6, "um") if unit_of(v) == "m" else (1e3, "mA")


def make_figures(art: dict, out_dir: Path) -> list[str]:
    """Draw the figures into ``out_dir``; return their file names."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    from scipy import signal

    from .residual import ljung_box, xcorr_with_bounds

    rec, split, search = art["record"], art["split"], art["search"]
    meas = views(rec.channels)
    before = views(art["nominal"])
    after = views(search.final)
    hold = split.hold
    fs = rec.fs_hz
    t = np.arange(rec.n)[hold] / fs
    ft_n = search.final_features or search.nominal_features
    sig = ft_n.sigma if ft_n is not None else {}
    names = []

    fig, axs = plt.subplots(len(_PLOT_VIEWS), 1, figsize=(10, 2.0 * len(_PLOT_VIEWS)), sharex=True)
    for ax, v in zip(axs, _PLOT_VIEWS):
        k, u = _scale(v)
        ax.plot(t, k * (meas[v][hold] - before[v][hold]), lw=0.5, color="tab:red", label="nominal model")
        ax.plot(t, k * (meas[v][hold] - after[v][hold]), lw=0.5, color="tab:blue", label="with effects found")
        if v in sig:
            ax.axhline(2 * k * sig[v], color="k", lw=0.6, ls="--")
            ax.axhline(-2 * k * sig[v], color="k", lw=0.6, ls="--", label="2 x noise")
        ax.set_ylabel(f"{v} ({u})")
    axs[0].legend(loc="upper right", fontsize=7, ncol=3)
    axs[-1].set_xlabel("time (s), held-out part")
    fig.suptitle("Residual (measured - model), held-out part")
    fig.tight_layout()
    fig.savefig(out_dir / "residual_time.png", dpi=90)
    plt.close(fig)
    names.append("residual_time.png")

    nper = int(2 ** max(8, min(15, int(np.log2(max((hold.stop - hold.start) // 4, 256))))))
    fig, axs = plt.subplots(3, 3, figsize=(13, 9))
    for ax, v in zip(axs.ravel(), _PLOT_VIEWS):
        k, u = _scale(v)
        for m, col, lab in ((before, "tab:red", "nominal"), (after, "tab:blue", "with effects")):
            f, p = signal.welch(k * (meas[v][hold] - m[v][hold]), fs=fs, nperseg=nper)
            if np.any(p[1:] > 0):        # a channel reproduced exactly has nothing to draw
                ax.loglog(f[1:], np.sqrt(np.maximum(p[1:], 1e-300)), lw=0.6, color=col, label=lab)
        if v in sig:
            ax.axhline(k * sig[v] * np.sqrt(2 / fs), color="k", lw=0.6, ls="--", label="noise floor")
        ax.set_title(v, fontsize=9)
        ax.set_ylabel(f"{u}/sqrt(Hz)", fontsize=8)
    axs[0, 0].legend(fontsize=7)
    for ax in axs[-1]:
        ax.set_xlabel("frequency (Hz)")
    fig.suptitle("Residual amplitude spectral density, held-out part")
    fig.tight_layout()
    fig.savefig(out_dir / "residual_spectra.png", dpi=90)
    plt.close(fig)
    names.append("residual_spectra.png")

    if search.rounds:
        ev = search.rounds[0]["evidence"]
        labels = list(ev)
        sc = [max(ev[n]["score_chi2"], 1e-1) for n in labels]
        cols = ["tab:green" if ev[n]["significant"] else "0.7" for n in labels]
        found = {a["name"] for a in search.accepted}
        fig, ax = plt.subplots(figsize=(8, 3.5))
        ax.barh(labels, sc, color=cols)
        ax.set_xscale("log")
        for i, n in enumerate(labels):
            txt = f"log10 p = {ev[n]['log10_p']:.1f}" + ("   FOUND" if n in found else "")
            ax.text(sc[i], i, " " + txt, va="center", fontsize=7)
        ax.set_xlabel("evidence: residual chi-square the signature explains (before fitting)")
        ax.set_title("Signature evidence per library effect (green: significant)")
        fig.tight_layout()
        fig.savefig(out_dir / "evidence.png", dpi=90)
        plt.close(fig)
        names.append("evidence.png")

    fig, axs = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    from .residual import compute_features

    drew = False
    for m, ls, lab in ((before, "-", "nominal"), (after, "--", "with effects")):
        ft = compute_features(rec, art["fit_frame"], meas, m, art["settings"])
        for name, r in ft.ratios.items():
            if name not in ("x", "y_sensor"):
                continue
            axs[0].semilogx(r["f_hz"], 20 * np.log10(np.abs(r["R"])), ls, marker=".", label=f"{r['path']} ({lab})")
            axs[1].semilogx(r["f_hz"], np.degrees(np.unwrap(np.angle(r["R"]))), ls, marker=".", label=f"{r['path']} ({lab})")
            drew = True
    if drew:
        axs[0].set_ylabel("gain ratio (dB)")
        axs[1].set_ylabel("phase ratio (deg)")
        axs[1].set_xlabel("frequency (Hz), excited lines")
        axs[0].legend(fontsize=7)
        fig.suptitle("Measured / model ratio of the sensor paths (1 = 0 dB, 0 deg when the model is right)")
        fig.tight_layout()
        fig.savefig(out_dir / "sensor_ratio.png", dpi=90)
        names.append("sensor_ratio.png")
    plt.close(fig)

    fig, axs = plt.subplots(2, 2, figsize=(11, 6))
    lags = art["settings"].ljung_box_lags
    for j, v in enumerate(("y_ss", "d_y") if "y" in rec.excited_axes or not rec.excited_axes else ("x_meas", "d_x")):
        for m, col, lab in ((before, "tab:red", "nominal"), (after, "tab:blue", "with effects")):
            e = meas[v][hold] - m[v][hold]
            _, p, rho = ljung_box(e, lags)
            axs[0, j].plot(np.arange(1, lags + 1), rho, marker=".", color=col, label=f"{lab} (Ljung-Box p = {p:.2g})")
            if rec.excited_axes:
                ax0 = rec.excited_axes[-1]
                fmax = float(np.max(rec.lines_hz)) if rec.lines_hz is not None else fs / 20
                xc = xcorr_with_bounds(e, rec.signal[ax0][hold], fs, fmax, 0.05)
                axs[1, j].plot(1e3 * xc["lag_s"], xc["r"], lw=0.7, color=col, label=lab)
                axs[1, j].axhline(xc["bound"], color="k", ls="--", lw=0.6)
                axs[1, j].axhline(-xc["bound"], color="k", ls="--", lw=0.6)
                axs[1, j].set_title(f"cross-correlation of the {v} residual with the {ax0} excitation", fontsize=8)
        n = hold.stop - hold.start
        b = 2.576 / np.sqrt(n)
        axs[0, j].axhline(b, color="k", ls="--", lw=0.6)
        axs[0, j].axhline(-b, color="k", ls="--", lw=0.6)
        axs[0, j].set_title(f"autocorrelation of the {v} residual (99 % bounds)", fontsize=8)
        axs[0, j].legend(fontsize=7)
        axs[0, j].set_xlabel("lag (samples)")
        axs[1, j].set_xlabel("lag (ms)")
    fig.tight_layout()
    fig.savefig(out_dir / "whiteness.png", dpi=90)
    plt.close(fig)
    names.append("whiteness.png")
    return names
