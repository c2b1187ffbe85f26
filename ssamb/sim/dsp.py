r"""What the DSP computes (compiled with numba): converters, position PID, DCM self-sensing.

Everything here reads only what a DSP has: the converter outputs (sampled coil currents and the
x probe after analog noise and quantisation), the PWM schedule it commands (duty cycles, edges,
its own dead time) and its calibration (turns, pole area, airgap and iron length of eq. (2),
gain and offset from the clamped-rotor calibration). Nothing reads the simulator's eddy model,
flux or true position.

Converters
----------
:func:`adc` quantises a sample (mid-tread, step :math:`q = 2 r / 2^b` over :math:`\pm r`,
clipped to the code range); the analog noise is added before, by the kernel.

DCM self-sensing (paper section 2.1, eq. (2))
----------------------------------------------
The coil equation (1) without the motion term, read as eq. (2) over a sampling interval:
:math:`L\,\Delta i = \Delta\Lambda`, the current changes by the volt-seconds the amplifier applied
less the resistive drop, :math:`\Lambda_k = \int_{t_0}^{t_k} (v - R i)\,dt`, over the
incremental inductance. The DSP knows :math:`\int v\,dt` exactly from its PWM timer (supply
voltage, duty cycle of every period, the edges and the dead time) -- the duty and ripple-phase
compensation -- and subtracts :math:`R i\,dt` with its calibrated resistance and the sampled
current (trapezoidal). Without that term the drift :math:`R i` between two samples reads as
ripple (see README, simulator notes). Over the last :math:`W` samples (``selfsensing.window_samples``) two
estimators of :math:`a = 1/L` are available (``selfsensing.estimator``):

``lsq``
    least squares :math:`i_k = \sum_m c_m P_m(k) + a\,\Lambda_k` with a polynomial trend of
    order ``trend_order`` (the resistive drop :math:`R i`, the motion EMF and the slow control
    current) as the only nuisance terms -- generic, no regressor shaped like any eddy model;
``peak``
    the maximum and minimum of the sampled ripple in the window,
    :math:`a = (i_{max} - i_{min})/(\Lambda_{k_{max}} - \Lambda_{k_{min}})` (the paper's
    direct current measurement: the peak ripple with duty and ripple-phase compensation).

The airgap follows from eq. (2), :math:`2 g = \mu_0 N^2 A_p a - l_{eq}/\mu_r`,
:math:`y = (2 g_0 - 2 g)/(2\cos\alpha)`, calibrated (gain, offset) and low-passed by
``lowpass_order`` cascaded first-order sections. A window without ripple (an amplifier
saturated at D = 0 or 1) or with :math:`a \le 0` holds the last estimate; so does an ``lsq``
window whose rms residual exceeds ``residual_gate`` times the rms of the fitted ripple (a
current step the model cannot explain), counted in the state ``D_REJ``.
"""
from __future__ import annotations

import functools
import math

import numba as nb
import numpy as np

from .magnetics import FASTMATH, NO_NRT
from .params import (MU0, P_AP, P_COSA, P_FS, P_G0, P_LEQ, P_MUR, P_N, P_PID_AD, P_PID_BD, P_PID_KI_HALF,
                     P_PID_KP, P_SS_ALPHA, P_SS_EST, P_SS_GAIN, P_SS_GATE, P_SS_MIN, P_SS_OFF,
                     P_SS_ORDER, P_SS_R, P_SS_W, P_TPWM, P_UMAX, P_V)

__all__ = ["SS_RING", "adc", "pid_step", "trend_basis", "dcm_update", "selfsensing_state"]

_HOT = dict(cache=True, error_model="numpy", fastmath=FASTMATH, **NO_NRT)

SS_RING = 64         # DCM window buffer length (samples)

# indices into the DCM state vector (see selfsensing_state)
D_N = 0              # samples pushed
D_LAM = 1            # volt-seconds applied to ypos since the last sample
D_RAW = 2            # last raw (uncalibrated) estimate (m)
D_OUT = 3            # output of the low-pass (m)
D_REJ = 4            # windows rejected by the residual gate
D_LP = 5             # 4 low-pass stages (m)
D_SIZE = 9


def selfsensing_state(y0: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """DCM state vector (low-pass at ``y0``) and its buffers (rings of currents and volt-seconds,
    and the contiguous window), one row each of a (3, 2 SS_RING) array."""
    s = np.zeros(D_SIZE)
    s[D_RAW] = y0
    s[D_OUT] = y0
    s[D_LP:D_LP + 4] = y0
    return s, np.zeros((3, 2 * SS_RING))


@functools.lru_cache(maxsize=16)
def trend_basis(window: int, order: int) -> np.ndarray:
    """Discrete orthonormal polynomial basis (order+1 rows, ``window`` columns) for the DCM trend.

    Rows span the polynomials of degree <= ``order`` on the sample indices of the window and
    are orthonormal (QR of the Vandermonde matrix), so projecting them out is a few dot products.
    The array is shared between calls (memoised): read it, never write it.
    """
    tn = np.linspace(-1.0, 1.0, window)
    v = np.vander(tn, order + 1, increasing=True)
    qm, _ = np.linalg.qr(v)
    return np.ascontiguousarray(qm.T)


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def adc(v, q, inv_q, cmax):
    """Quantise ``v`` with step ``q`` (``inv_q`` = 1/q; mid-tread) and codes ``-cmax-1 .. cmax``;
    ``q = 0``: ideal."""
    if q <= 0.0:
        return v
    c = math.floor(v * inv_q + 0.5)
    if c > cmax:
        c = cmax
    elif c < -cmax - 1.0:
        c = -cmax - 1.0
    return c * q


@nb.njit(**_HOT)
def pid_step(st, p, base, e):
    """Tustin PID: u = Kp e + I + D (state: I, D, previous error at st[base..base+2]), clamped
    at +/- ``u_max_a`` with conditional integration (see :mod:`ssamb.sim.controller`)."""
    i_old = st[base]
    i_new = i_old + p[P_PID_KI_HALF] * (e + st[base + 2])
    d_new = p[P_PID_AD] * st[base + 1] + p[P_PID_BD] * (e - st[base + 2])
    u = p[P_PID_KP] * e + i_new + d_new
    umax = p[P_UMAX]
    if u > umax:
        u = umax
        if e > 0.0:
            i_new = i_old
    elif u < -umax:
        u = -umax
        if e < 0.0:
            i_new = i_old
    st[base] = i_new
    st[base + 1] = d_new
    st[base + 2] = e
    return u


@nb.njit(inline="always", **_HOT)
def _fit_lsq(p, win, w, tb):
    """Least-squares ``1/L`` over the window (trend projected out); 0.0 if degenerate or gated.

    ``win`` holds the window's volt-seconds at ``[0, w)`` and currents at ``[SS_RING, SS_RING + w)``.
    Returns ``(a, rejected)``.
    """
    npoly = tb.shape[0]
    sll = 0.0
    sli = 0.0
    sii = 0.0
    for q in range(w):
        lq = win[q]
        ii = win[SS_RING + q]
        sll += lq * lq
        sli += lq * ii
        sii += ii * ii
    for m in range(npoly):
        tl = 0.0
        ti = 0.0
        for q in range(w):
            bm = tb[m, q]
            tl += bm * win[q]
            ti += bm * win[SS_RING + q]
        sll -= tl * tl
        sli -= tl * ti
        sii -= ti * ti
    vt = p[P_V] * p[P_TPWM] * 0.25          # ripple volt-seconds of a period at D = 1/2
    if sll < p[P_SS_MIN] * vt * vt * w:     # no ripple left after the trend (saturated amplifier)
        return 0.0, False
    a = sli / sll
    dof = w - npoly - 1
    rss = max(sii - a * sli, 0.0)
    if dof > 0 and rss / dof > (p[P_SS_GATE] * a) ** 2 * sll / w:
        return 0.0, True
    return a, False


@nb.njit(inline="always", **_HOT)
def _fit_peak(p, win, w):
    """Peak estimate ``1/L`` from the largest and smallest sample of the window (0.0 if degenerate)."""
    kmax = 0
    kmin = 0
    imax = win[SS_RING]
    imin = imax
    for q in range(1, w):
        ii = win[SS_RING + q]
        if ii > imax:
            imax = ii
            kmax = q
        elif ii < imin:
            imin = ii
            kmin = q
    dl = win[kmax] - win[kmin]
    if dl <= p[P_SS_MIN] * p[P_V] * p[P_TPWM]:
        return 0.0
    return (imax - imin) / dl


@nb.njit(**_HOT)
def dcm_update(s, p, ring_i, ring_l, win, i_samp, tb):
    r"""Push one ypos current sample (and the volt-seconds since the last one) and update the
    estimate (see the module docstring). ``win`` is a work array of ``2 SS_RING`` entries.
    The fits (:func:`_fit_lsq`, :func:`_fit_peak`) are inlined here (no arrays passed per sample)."""
    w = int(p[P_SS_W])
    nidx = int(s[D_N])
    slot = nidx % SS_RING
    ring_i[slot] = i_samp
    # volt-seconds since the last sample, less the resistive drop R i dt (trapezoidal, sampled current)
    i_prev = ring_i[(nidx - 1) % SS_RING] if nidx > 0 else i_samp
    ring_l[slot] = s[D_LAM] - p[P_SS_R] * 0.5 * (i_prev + i_samp) / p[P_FS]
    s[D_LAM] = 0.0
    nidx += 1
    s[D_N] = nidx
    if nidx < w:
        return
    first = nidx - w
    acc = 0.0
    for q in range(w):                      # the window, contiguous: volt-seconds and currents
        k = (first + q) % SS_RING
        if q > 0:
            acc += ring_l[k]
        win[q] = acc
        win[SS_RING + q] = ring_i[k]
    if p[P_SS_EST] > 0.5:
        a = _fit_peak(p, win, w)
    else:
        a, rej = _fit_lsq(p, win, w, tb)
        if rej:
            s[D_REJ] += 1.0
    if a <= 0.0:
        return
    n = p[P_N]
    g2 = MU0 * n * n * p[P_AP] * a - p[P_LEQ] / p[P_MUR]
    y_raw = (2.0 * p[P_G0] - g2) / (2.0 * p[P_COSA])
    s[D_RAW] = y_raw
    u = p[P_SS_GAIN] * y_raw + p[P_SS_OFF]
    for q in range(int(p[P_SS_ORDER])):
        s[D_LP + q] += p[P_SS_ALPHA] * (u - s[D_LP + q])
        u = s[D_LP + q]
    s[D_OUT] = u
