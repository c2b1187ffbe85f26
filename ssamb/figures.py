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

__all__ = ["identification_figures", "fig4", "fig9", "save"]

_UNIT = {"x_meas": "um", "y_meas": "um", "y_ss": "um", "i_ypos": "A", "i_yneg": "A", "i_xpos": "A",
         "i_xneg": "A", "u_x": "A", "u_y": "A"}


def _scale(name):
    return 1e6 if _UNIT.get(name) == "um" else 1.0


def save(fig, path: str | Path) -> None:
    from .io import atomic_path

    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight", format="png")
    plt.close(fig)


def identification_figures(info: Mapping, model, u_val, y_val, fs_hz: float, fig_dir: Path) -> None:
    """Order scan (validation fit and singular values vs order) and validation overlay."""
    from .ident import auto_horizon

    fig_dir = Path(fig_dir)
    sub = info["subsystem"]
    scan = info["order_scan"]
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.4))
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
    save(fig, fig_dir / f"{sub}_orders.png")
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
    axs[0, 0].set_title(f"{sub}: validation data, fit " + ", ".join(f"{k} {v:.1f} %" for k, v in info["fit_pct"].items()))
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
