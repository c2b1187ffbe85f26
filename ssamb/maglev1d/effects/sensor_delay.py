r"""``sensor_delay``: the position reaches the controller late.

Physics: the controller samples the position the ball had :math:`\tau` earlier (the optical
sensor's filter, the ADC's conversion, the serial link), :math:`0 \le \tau < T_s`; the replay
reads the trajectory between its integration steps (cubic Hermite), so :math:`\tau` is
continuous (knob ``sensor_delay_s``; delays of several effects add).

Signature: the position over the coil current (path ``y/i``, measured over model) lags with a
phase linear in frequency, :math:`\angle R = -2\pi f\tau`, at a flat gain; the current over the
command (``i/u``) is unchanged. Evidence: :math:`(\hat\tau/\sigma_\tau)^2` of ``y/i``, one-sided,
unless ``i/u`` leads significantly (the signature of ``eddy_current``).

Fit: :math:`\tau`, started at the path's slope (or a coarse grid).
"""
from __future__ import annotations

from ._common import TS_S, delay_evidence, delay_model, entries, number, ratio_claim, ratio_evidence

NAME = "sensor_delay"
REQUIRED = ("delay_s",)
OPTIONAL = ()
SIGNATURE = "phase lag of the position over the coil current, linear in frequency; current over command unchanged"
SEARCHABLE = True
NEEDS_HINT = False
KNOB = "sensor_delay_s"


def validate(p: dict, where: str) -> dict:
    return {"delay_s": number(p, "delay_s", where, 0.0, TS_S, hi_open=True)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] = min(kn[KNOB] + float(e["delay_s"]), TS_S)


def evidence(ft, alpha: float, st) -> dict:
    ev = delay_evidence(ft, alpha, "y/i")
    lead = ratio_evidence(ft, alpha, "i/u", "tau", -1)
    if lead["significant"]:                 # the current leads the command: the force lags (eddy_current)
        ev.update(score=0.0, significant=False)
        ev["details"]["i/u"] = lead["details"]
        ev["hints"].pop("delay_s", None)
    return ev


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return ratio_claim(ft, "y/i", "tau")


def model(hints: dict, record, st):
    return delay_model(NAME, hints)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
