r"""``actuation_delay``: the new command reaches the coil late.

Physics: the voltage computed from the samples at :math:`t_k` is applied from
:math:`t_k + \tau` (the computation, the serial round trip, the PWM's update at its next
period), the previous one until then, :math:`0 \le \tau < T_s` (knob ``actuation_delay_s``; the
replay splits the sample interval there, so :math:`\tau` is continuous).

Signature: the current over the command (path ``i/u``) lags with a phase linear in frequency;
the position over the current (``y/i``) is unchanged (the force follows the current).
Evidence: :math:`(\hat\tau/\sigma_\tau)^2` of ``i/u``, one-sided.

Fit: :math:`\tau`, started at the path's slope (or a coarse grid).
"""
from __future__ import annotations

from ._common import TS_S, delay_evidence, delay_model, entries, number, ratio_claim

NAME = "actuation_delay"
REQUIRED = ("delay_s",)
OPTIONAL = ()
SIGNATURE = "phase lag of the coil current over the command, linear in frequency; position over current unchanged"
SEARCHABLE = True
NEEDS_HINT = False
KNOB = "actuation_delay_s"


def validate(p: dict, where: str) -> dict:
    return {"delay_s": number(p, "delay_s", where, 0.0, TS_S, hi_open=True)}


def apply(kn: dict, e: dict, cfg) -> None:
    kn[KNOB] = min(kn[KNOB] + float(e["delay_s"]), 0.99 * TS_S)


def evidence(ft, alpha: float, st) -> dict:
    return delay_evidence(ft, alpha, "i/u")


def claim(ft, hints: dict, df_hz: float, st) -> float:
    return ratio_claim(ft, "i/u", "tau")


def model(hints: dict, record, st):
    return delay_model(NAME, hints)


def report(m, theta, se, significant) -> list[dict]:
    return entries(m, theta, se)
