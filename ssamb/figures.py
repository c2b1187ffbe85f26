"""Figures of the workflow stages (matplotlib, Agg backend, PNG files for the report).

Each function draws one stage's figures from its data and writes PNGs; the report embeds
them. Units are in every axis label.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["failure_figure", "identification_figures", "fig4", "plot_weight", "fig7", "fig8", "fig9", "save"]

_UNIT = {"x_meas": "um", "y_meas": "um", "y_ss": "um", "i_ypos": "A", "i_yneg": "A", "i_xpos": "A",
         "i_xneg": "A", "u_x": "A", "u_y": "A"}


def _scale(name):
    return 1e6 if _UNIT.get(name) == "um" else 1.0


def save(fig, path: str | Path) -> None:
    from .io import atomic_path

    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    plt.close(fig)


def failure_figure(stage: str, reason: str, path: str | Path) -> None:
    """A figure that states that a stage failed and why (written in place of its figure)."""
    import textwrap

    fig, ax = plt.subplots(figsize=(8.5, 2.2))
    ax.axis("off")
    ax.text(0.01, 0.95, f"{stage} failed", fontsize=12, color="C3", va="top", weight="bold")
    ax.text(0.01, 0.65, "\n".join(textwrap.wrap(reason, 110)[:6]), fontsize=8, va="top", family="monospace")
    save(fig, path)


def _order_figure(info: Mapping, path: Path) -> None:
    """Fit and SIPPY singular values against order (or a note when the run has no order scan)."""
    scan, sub = info["order_scan"], info["subsystem"]
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.4))
    if scan is None:
        for a in ax:
            a.axis("off")
        ax[0].text(0.0, 0.5, f"{sub}: no order scan in this run (identification.order_scan.orders is empty)")
        save(fig, path)
        return
    orders = np.asarray(scan["orders"])
    ax[0].plot(orders, scan["mean_fit"], "o-")
    ax[0].axvline(info["order"], color="C3", ls="--", label=f"selected order {info['order']}")
    ax[0].set_xlabel("model order")
    ax[0].set_ylabel("mean validation fit (%)")
    ax[0].set_ylim(max(-50, np.nanmin(scan["mean_fit"]) - 5), 102)
    ax[0].legend()
    ax[0].set_title(f"{sub}: fit vs order ({scan['method']})")
    sv = scan.get("singular_values")
    if sv:
        sv = np.asarray(sv)
        ax[1].semilogy(np.arange(1, len(sv) + 1), sv, "o-")
        ax[1].axvline(info["order"], color="C3", ls="--")
        ax[1].set_xlim(0.5, min(len(sv), 20) + 0.5)
        ax[1].set_xlabel("index")
        ax[1].set_ylabel("singular value (-)")
        ax[1].set_title("SIPPY subspace singular values")
    fig.tight_layout()
    save(fig, path)


def identification_figures(info: Mapping, model, u_val, y_val, fs_hz: float, fig_dir: Path) -> None:
    """Order scan (validation fit and singular values vs order) and validation overlay."""
    from .identification import auto_horizon

    fig_dir = Path(fig_dir)
    sub = info["subsystem"]
    _order_figure(info, fig_dir / f"{sub}_orders.png")
    # validation overlay (first 0.1 s)
    n = min(len(u_val), int(0.1 * fs_hz))
    u, y = np.asarray(u_val)[:n], np.asarray(y_val)[:n]
    horizon = auto_horizon(model.A, n)
    if horizon is None:
        yhat = model.simulate(u)
        how = "simulation"
    else:
        yhat = model.predict(u, y, horizon)
        how = f"{horizon}-step prediction (unstable model)"
    t = np.arange(n) / fs_hz * 1e3
    outs = info["outputs"]
    fig, axs = plt.subplots(len(outs), 1, figsize=(10, 1.9 * len(outs) + 0.6), sharex=True, squeeze=False)
    for i, name in enumerate(outs):
        s = _scale(name)
        axs[i, 0].plot(t, y[:, i] * s, lw=1, label="nonlinear simulation")
        axs[i, 0].plot(t, np.asarray(yhat)[:, i] * s, lw=1, label=f"model ({how})")
        axs[i, 0].set_ylabel(f"{name} ({_UNIT.get(name, '-')})")
    axs[0, 0].legend(loc="upper right", fontsize=8)
    axs[-1, 0].set_xlabel("time (ms)")
    fits = ", ".join(f"{k} {v:.1f} %" for k, v in info["fit_pct"].items())
    axs[0, 0].set_title(f"{sub}: validation data, fit {fits}")
    fig.tight_layout()
    save(fig, fig_dir / f"{sub}_validation.png")


def fig4(nl: Mapping, lti: Mapping, fits: Mapping, path: str | Path) -> None:
    """Paper Fig. 4: nonlinear simulation vs closed-loop LTI model, x and y."""
    fig, axs = plt.subplots(2, 1, figsize=(10, 5.2), sharex=True)
    t = np.asarray(nl["t"])
    for ax, name in zip(axs, ("x_meas", "y_meas")):
        ax.plot(t, np.asarray(nl[name]) * 1e6, lw=1, label="nonlinear simulation")
        ax.plot(t, np.asarray(lti[name]) * 1e6, lw=1, label=f"closed-loop LTI model (fit {fits[name]:.1f} %)")
        ax.set_ylabel(f"{name[0]} position (um)")
        ax.legend(loc="upper right", fontsize=8)
    axs[-1].set_xlabel("time (s)")
    axs[0].set_title("Fig. 4 equivalent: response to current pulses injected before the amplifiers")
    fig.tight_layout()
    save(fig, path)


def plot_weight(ax, fit, etfe_freqs_hz=None, etfe_mag=None, *, unit: str = "m/A",
                f_plot_hz: tuple[float, float] | None = None, title: str | None = None):
    """Fig. 7 equivalent on a matplotlib axis: ETFE points, envelope, fitted |W| and the
    +/- ``tol_db`` band around the envelope (:class:`ssamb.uncertainty.WeightFit`), log frequency
    axis in Hz, magnitude in dB re 1 ``unit`` (the unit of the mismatch). ``etfe_*`` default to
    the data stored in the envelope. Returns ``ax``."""
    env = fit.envelope
    fe = env.freqs_hz if etfe_freqs_hz is None else np.asarray(etfe_freqs_hz, float)
    me = env.mag if etfe_mag is None else np.asarray(etfe_mag, float)
    f_lo, f_hi = fit.band_hz
    lo, hi = f_plot_hz if f_plot_hz is not None else (f_lo / 10.0, max(env.f_rolloff_hz, f_hi) * 10.0)
    fp = np.logspace(np.log10(lo), np.log10(hi), 600)
    fb = np.logspace(np.log10(f_lo), np.log10(f_hi), 300) if f_hi > f_lo else np.array([f_lo])
    eb = env.db(fb)
    ax.fill_between(fb, eb - fit.tol_db, eb + fit.tol_db, color="0.85", label=f"envelope ±{fit.tol_db:g} dB")
    ax.semilogx(fp, env.db(fp), "k--", lw=1.0, label="peak envelope (extended)")
    ax.semilogx(fp, fit.db(fp), "C0-", lw=1.8, label=f"|W| (order {fit.order}, max dev {fit.max_dev_db:.2f} dB)")
    ax.semilogx(fe, 20 * np.log10(np.maximum(me, np.max(me) * 1e-12)), "C3o", ms=4,
                label="ETFE |Y/X − Ȳ/X̄| (eq. 6)")
    ax.set_xscale("log")
    ax.set_xlabel("Frequency (Hz)")
    ax.set_ylabel(f"Magnitude (dB re 1 {unit})")
    if title:
        ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return ax


def fig7(fit, freqs_hz, etfe_mag, unit: str, what: str, path: str | Path) -> None:
    """Paper Fig. 7: the mismatch ETFE, its envelope and the fitted weight."""
    fig, ax = plt.subplots(figsize=(8.5, 4.0))
    plot_weight(ax, fit, freqs_hz, etfe_mag, unit=unit,
                title=f"Fig. 7 equivalent: additive uncertainty weight, {what}")
    save(fig, path)


def fig8(sweep, case: str, path: str | Path) -> None:
    """Paper Fig. 8: μ bounds over frequency (:class:`ssamb.robustness.MuSweep`) and the peak."""
    fig, ax = plt.subplots(figsize=(8.5, 3.8))
    ax.loglog(sweep.freqs_hz, sweep.upper, label="upper bound")
    ax.loglog(sweep.freqs_hz, sweep.lower, "--", label="lower bound")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.plot([sweep.peak_hz], [sweep.peak], "rv", label=f"peak {sweep.peak:.3g} at {sweep.peak_hz:.3g} Hz")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("mu (-)")
    ax.set_title(f"Fig. 8 equivalent: mu for additive uncertainty, case '{case}'")
    ax.legend(fontsize=8)
    save(fig, path)


def fig9(t, responses: Mapping[str, Mapping], clearance_m: float, sweep_hz, path: str | Path) -> None:
    """Paper Fig. 9: responses to the frequency sweep, with the backup-bearing clearance."""
    fig, axs = plt.subplots(2, 1, figsize=(10, 5.6), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    t = np.asarray(t)
    for name, r in responses.items():
        radial = np.hypot(np.asarray(r["x"]), np.asarray(r["y"]))
        axs[0].plot(t, np.asarray(r["y"]) * 1e6, lw=1, label=f"{name}: y")
        if name == "nonlinear":
            axs[0].plot(t, radial * 1e6, lw=0.8, color="k", alpha=0.4, label="nonlinear: radial")
    for s in (1, -1):
        axs[0].axhline(s * clearance_m * 1e6, color="C3", ls="--", lw=1)
    axs[0].set_ylabel("position (um)")
    axs[0].legend(loc="upper left", fontsize=7, ncol=2)
    axs[0].set_title("Fig. 9 equivalent: responses to the frequency sweep (dashed: backup-bearing clearance)")
    axs[1].plot(t, sweep_hz)
    axs[1].set_ylabel("sweep (Hz)")
    axs[1].set_xlabel("time (s)")
    fig.tight_layout()
    save(fig, path)
