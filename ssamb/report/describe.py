"""Report phrases built from the config (no experiment figure is typed into the report)."""
from __future__ import annotations

from typing import Any, Mapping

__all__ = ["um", "khz", "excitation"]


def um(m: float) -> str:
    """A length in micrometres, e.g. ``'100 µm'``."""
    return f"{m * 1e6:.3g} µm"


def khz(hz: float) -> str:
    """A frequency in kHz, e.g. ``'83.3 kHz'``."""
    return f"{hz / 1e3:.4g} kHz"


def excitation(exc: Mapping[str, Any]) -> str:
    """One phrase for an experiment's excitation (kind, amplitude, band, axis)."""
    kind = exc.get("kind")
    axis = exc.get("axis", "y")
    axes = "both axes" if axis == "both" else f"the {axis} axis"
    if kind == "multisine":
        per_line = exc.get("amplitude_definition", "peak") == "per_line"
        return (f"{um(exc['amplitude_m'])} {'per line ' if per_line else ''}random-phase multisine "
                f"({exc['f_min_hz']:g}–{exc['f_max_hz']:g} Hz, {exc['f_resolution_hz']:g} Hz lines) on {axes}")
    if kind == "sweep":
        return (f"{um(exc['amplitude_m'])} {exc.get('law', 'linear')} sweep from {exc['f_start_hz']:g} to "
                f"{exc['f_stop_hz']:g} Hz in {exc['sweep_duration_s']:g} s on {axes}")
    if kind == "pulses":
        return (f"rectangular {exc['amplitude_a']:g} A current pulses ({exc['min_width_s'] * 1e3:g}–"
                f"{exc['max_width_s'] * 1e3:g} ms wide) injected before the amplifiers on {axes}")
    if kind in (None, "none"):
        return "no excitation"
    return f"a {kind} excitation"
