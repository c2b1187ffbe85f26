r"""The rig's controller, as its acquisition program runs it, and the check against the logs.

Reconstructed from ``adquisicion_datos.py`` of the source repository (read, not copied): every
:math:`T_s` = 10 ms the position ADC count :math:`p` and the current ADC count :math:`c` arrive,
and

.. math::

    y_k &= q_y\,p_k, \qquad i_k = q_i\,c_k, \qquad e_k = y_{d,k} - y_k \\
    I_k &= \begin{cases} I_{k-1} + k_i T_s e_k & |I_{k-1}| < I_{ref} \\
                         \operatorname{clip}(I_{k-1}, \pm 0.95 I_{ref}) & \text{otherwise} \end{cases} \\
    i_{d,k} &= -\operatorname{clip}\big(k_p e_k + I_k + k_d (e_k - e_{k-1})/T_s,\; -I_{ref},\; 0\big) \\
    \epsilon_k &= i_{d,k} - i_k \\
    J_k &= \begin{cases} J_{k-1} + k_{ii} T_s \epsilon_k & |J_{k-1}| < V_{ref} \\
                         \operatorname{clip}(J_{k-1}, \pm 0.95 V_{ref}) & \text{otherwise} \end{cases} \\
    u_k &= \operatorname{clip}(k_{pi}\epsilon_k + J_k,\; 0,\; V_{ref})

with :math:`e_{-1} = I_{-1} = J_{-1} = 0` when the program starts (the derivative's first step
is a kick). ``y`` grows downwards (away from the magnet): a ball below the reference
(:math:`e < 0`) raises the current demand :math:`i_d \in [0, I_{ref}]`.

:func:`check` runs this controller on a log's own ``y``, ``i``, ``yd`` (the logged values rounded
back to whole ADC counts, which is what the controller saw) and compares its command with the
logged ``u``: how many samples agree within the log's rounding (``u`` is written with 4
decimals) and within one PWM step (:math:`V_{ref}/254`), and the rms difference.
"""
from __future__ import annotations

from typing import Mapping

import numba
import numpy as np

__all__ = ["GAIN_KEYS", "gains_of", "step", "run", "check"]

#: the controller's settings in the device config (``controller`` section), in kernel order
GAIN_KEYS = ("ts_s", "kp_a_per_m", "ki_a_per_m_s", "kd_a_s_per_m", "kpi_v_per_a", "kii_v_per_a_s",
             "i_ref_a", "v_ref_v")


def gains_of(cfg: Mapping) -> np.ndarray:
    """The controller's settings as the vector :func:`step` reads (order :data:`GAIN_KEYS`)."""
    c = cfg["controller"]
    return np.array([float(c[k]) for k in GAIN_KEYS])


@numba.njit(cache=True)
def _clip(x, lo, hi):
    return lo if x < lo else (hi if x > hi else x)


@numba.njit(cache=True)
def step(state, y, i, yd, g):
    """One controller sample; ``state`` = ``[e_prev, I, J, i_d]`` is updated in place.

    Returns the command :math:`u_k` (V). ``g``: :func:`gains_of`.
    """
    ts, kp, ki, kd, kpi, kii, iref, vref = g[0], g[1], g[2], g[3], g[4], g[5], g[6], g[7]
    e_prev = state[0]
    e = yd - y
    prop = kp * e
    der = kd * (e - e_prev) / ts
    integ = state[1]
    if -iref < integ < iref:
        integ += ki * ts * e
    else:
        integ = _clip(integ, -0.95 * iref, 0.95 * iref)
    idem = -_clip(prop + integ + der, -iref, 0.0)
    ei = idem - i
    intei = state[2]
    if -vref < intei < vref:
        intei += kii * ts * ei
    else:
        intei = _clip(intei, -0.95 * vref, 0.95 * vref)
    state[0] = e
    state[1] = integ
    state[2] = intei
    state[3] = idem
    return _clip(kpi * ei + intei, 0.0, vref)


@numba.njit(cache=True)
def _run(y, i, yd, g, state0):
    n = len(y)
    u = np.empty(n)
    states = np.empty((n, 4))
    st = state0.copy()
    for k in range(n):
        states[k] = st                     # the state before sample k
        u[k] = step(st, y[k], i[k], yd[k], g)
    return u, states


def run(y, i, yd, g, state0=None):
    """The controller over a whole log.

    Returns
    -------
    u : numpy.ndarray
        The commands (V).
    states : numpy.ndarray
        ``(n, 4)``: the state ``[e_prev, I, J, i_d]`` *before* each sample (what a replay that
        starts at that sample takes over).
    """
    st = np.zeros(4) if state0 is None else np.asarray(state0, float)
    return _run(np.asarray(y, float), np.asarray(i, float), np.asarray(yd, float), np.asarray(g, float), st)


def check(arrays: Mapping, cfg: Mapping, yd=None) -> dict:
    r"""Does the logged command follow from the logged signals? (module docstring)

    Parameters
    ----------
    arrays : mapping
        ``y, i, u, yd`` of a log.
    cfg : mapping
        The device config (controller gains, ADC steps, PWM steps).
    yd : array, optional
        A reference to use instead of the logged one (e.g. the reference's formula, which the
        log writes rounded to 1 um).

    Returns
    -------
    dict
        ``n``, ``within_rounding`` (fraction of samples with :math:`|\Delta u| \le` 0.5e-4 V plus
        float slack), ``within_pwm_step`` (:math:`\le V_{ref}/254`), ``rms_v``, ``max_abs_v``,
        ``first_mismatch`` (sample index or None).
    """
    qy, qi = position_lsb_m(cfg), current_lsb_a(cfg)
    y = qy * np.round(np.asarray(arrays["y"], float) / qy)
    i = qi * np.round(np.asarray(arrays["i"], float) / qi)
    ref = np.asarray(arrays["yd"] if yd is None else yd, float)
    u, _ = run(y, i, ref, gains_of(cfg))
    d = u - np.asarray(arrays["u"], float)
    pwm = float(cfg["controller"]["v_ref_v"]) / float(cfg["amplifier"]["pwm_steps"])
    ok = np.abs(d) <= 0.5e-4 + 1e-9
    return {"n": int(len(d)), "within_rounding": float(np.mean(ok)),
            "within_pwm_step": float(np.mean(np.abs(d) <= pwm)), "rms_v": float(np.sqrt(np.mean(d ** 2))),
            "max_abs_v": float(np.max(np.abs(d))), "first_mismatch": None if ok.all() else int(np.argmin(ok))}


def position_lsb_m(cfg: Mapping) -> float:
    """Metres per position ADC count (``esc_pos`` = full scale / counts)."""
    s = cfg["sensors"]
    return float(s["position_full_scale_m"]) / float(s["position_counts"])


def current_lsb_a(cfg: Mapping) -> float:
    """Amperes per current ADC count (ADC volts per count over the shunt resistance)."""
    s = cfg["sensors"]
    return float(s["current_full_scale_v"]) / (float(cfg["coil"]["r_shunt_ohm"]) * float(s["current_counts"]))
