r"""The compiled simulation kernel: event-exact PWM, magnetics, rotor, DSP in the loop.

Time is organised around the controller samples :math:`t_k = k/f_s` (83.3 kHz). At each
sample the kernel

1. evaluates every magnet's MMF exactly (saturation, hysteresis), the eddy MMF of the
   laminations and, with ``magnetics.cross_coupling``, the coupling MMF of the stator network
   (:mod:`ssamb.sim.network`, tables interpolated at the rotor position);
2. samples the converters of the DSP: the four coil currents and the x eddy-current probe
   (first-order bandwidth), each with analog noise and quantisation (``converters``); the y
   probe for evaluation alike;
3. runs DCM self-sensing on the ypos current sample (:func:`ssamb.sim.dsp.dcm_update`);
4. applies the sensor effects (gain, transport delay) and runs the two discrete PID
   controllers, which set the current references :math:`i_0 \pm u + \text{inj}` -- applied one
   sample later with ``converters.computation_delay_samples: 1``;
5. records one row of outputs;
6. integrates to :math:`t_{k+1}` in ``substeps`` sub-steps. Inside a sub-step every PWM event
   (period start with the PI update, turn-on edge, turn-off edge) is an exact breakpoint, so
   the switching edges -- and therefore the ripple peaks -- are resolved exactly; between
   breakpoints the coil voltage is constant and each magnet's flux is integrated for its MMF
   linearised about the sample (:func:`_segment`, :func:`_segment_ladder`), the rotor with the
   trapezoidal force average.

Amplifiers (two-state, paper section 2.2): centre-aligned PWM of period :math:`T`; the coil sees
:math:`+V` during :math:`[t_s + (1-D)T/2 + t_{dead},\ t_s + (1+D)T/2]` and :math:`-V` otherwise
(freewheeling through the diodes back into the supply). At every period start the PI loop
samples the current through the converter (the middle of the :math:`-V` interval, i.e. the
ripple average) and sets :math:`D = 1/2 + K_P e + \sum K_I e` clipped to
``[duty_min, duty_max]`` with conditional integration. The diodes forbid negative current:
when a step would reverse it, the coil is open (i = 0) and the flux decays through the eddy path.

Coupling between magnets is evaluated at the controller samples; inside a sample the other
magnets' coupling MMF is held (their flux changes by less than the ripple, and the coupling is
a fraction of a percent of the gap reluctance), which the sampled currents do not see.

Effects of the close-the-loop library act here as parameters (``DELAY_X/Y`` sensor transport
delay, ``GAIN_X/Y`` sensor scale error, ``DEADTIME`` turn-on delay of every PWM pulse, ``XCOUP``
extra flux coupling between adjacent magnets, on top of the network's) or as the external
force arrays (static load, unbalance, arbitrary forces).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from .dsp import D_LAM, D_OUT, D_RAW, adc, dcm_update, pid_step
from .magnetics import FASTMATH, MAX_PLAY, NO_NRT, gap_sum, mmf_update
from .params import (MAX_LADDER, P_CC, P_CDELAY, P_CLAMP, P_CLAMP_X, P_CLAMP_Y, P_CLEAR, P_DEADTIME,
                     P_DELAY_X, P_DELAY_Y, P_DMAX, P_DMIN, P_FORCE_K, P_FS, P_GAIN_X, P_GAIN_Y, P_GE,
                     P_GRAV, P_I_CMAX, P_I_INVQ, P_I_Q, P_IBIAS, P_INV_AP, P_INV_MASS, P_INV_N,
                     P_IREF_MAX, P_KC, P_KI_PA, P_KP_PA, P_LAD_C0, P_LAD_INVTAU, P_LAD_TAU, P_MASS, P_N,
                     P_NLAD, P_PID_ON, P_QHALF, P_R, P_SS_IDEAL, P_SUBSTEPS, P_TPWM, P_V, P_X_CMAX,
                     P_X_INVQ, P_X_Q, P_XCOUP, P_XNET, P_XS_BW)

# numba's on-disk cache (cache=True) is keyed on the content of this file only: after changing
# params.py (the P_* layout) or a compiled helper imported from another module, change this
# file too (or clear __pycache__), or stale machine code with old constants is reused.
# cache generation: 7 (fastmath: contract only, magnetics.FASTMATH; the logged rows only)

# helpers called every sample: no numba runtime (see magnetics.NO_NRT), no allocation
_HOT = dict(cache=True, error_model="numpy", fastmath=FASTMATH, **NO_NRT)

# ---- state vector indices ------------------------------------------------------------------
S_PHI = 0            # 4 fluxes per turn (Wb): ypos, yneg, xpos, xneg
S_X, S_Y, S_VX, S_VY = 4, 5, 6, 7
S_XS = 8             # x probe output (m)
S_PIDX_I, S_PIDX_D, S_PIDX_E = 9, 10, 11
S_PIDY_I, S_PIDY_D, S_PIDY_E = 12, 13, 14
S_UX, S_UY = 15, 16
S_INTEG = 17         # 4 PI integrators (duty)
S_DUTY = 21          # 4 duty cycles
S_VOLT = 25          # 4 coil voltage signs (+1 / -1)
S_PHASE = 29         # 4 PWM phases: 0 before turn-on, 1 on, 2 after turn-off
S_TON = 33           # 4 turn-on times
S_TOFF = 37          # 4 turn-off times
S_M = 41             # 4 PWM period counters
S_BLK = 45           # 4 diode-blocked flags
S_IREF = 49          # 4 current references applied by the amplifiers
S_IREFN = 53         # 4 current references computed, applied at the next sample (computation delay)
S_TCONTACT = 57      # first contact time (s), -1 if none
S_RIPMAX, S_RIPMIN, S_RIPN = 58, 59, 60   # ypos ripple tracker in the current period
S_DN = 61            # delay-buffer samples pushed
S_FMX, S_FMY = 62, 63
S_SIZE = 64

# ---- drive and noise rows ------------------------------------------------------------------
DRIVE_ROWS = ("r_x", "r_y", "inj_x", "inj_y", "f_x", "f_y")
NOISE_ROWS = ("x", "y", "i_ypos", "i_yneg", "i_xpos", "i_xneg")

# ---- output rows ---------------------------------------------------------------------------
OUT_NAMES = ("t", "x_meas", "y_meas", "y_ss", "i_ypos", "i_yneg", "i_xpos", "i_xneg", "u_x",
             "u_y", "x_true", "y_true", "b_ypos_t", "b_yneg_t", "b_xpos_t", "b_xneg_t",
             "duty_ypos", "duty_yneg", "duty_xpos", "duty_xneg", "contact", "f_mag_x_n",
             "f_mag_y_n", "y_ss_raw", "vx_m_per_s", "vy_m_per_s")
O = {name: i for i, name in enumerate(OUT_NAMES)}
N_OUT = len(OUT_NAMES)
O_T, O_XM, O_YM, O_YSS, O_I = 0, 1, 2, 3, 4
O_UX, O_UY, O_XT, O_YT, O_B, O_D, O_CONTACT, O_FMX, O_FMY, O_YSSRAW, O_VX, O_VY = (
    8, 9, 10, 11, 12, 16, 20, 21, 22, 23, 24, 25)
#: the rows of an output without the true states (:func:`run_chunk` with ``N_LOGGED`` rows): what
#: the DSP logs (the first rows of :data:`OUT_NAMES`), the contact flag and the raw self-sensed position
LOGGED_NAMES = OUT_NAMES[:O_XT] + ("contact", "y_ss_raw")
N_LOGGED = len(LOGGED_NAMES)
L_CONTACT, L_YSSRAW = N_LOGGED - 2, N_LOGGED - 1
RING = 256           # delay-buffer length (samples): up to 3 ms of transport delay

# ---- rows of the magnets' work array (one column per magnet), carried between the helpers --
M_F, M_DF, M_FE = 0, 1, 2    # MMF at the sample (carried through the sub-step), its slope, eddy MMF
M_S1, M_S2, M_VBAR = 3, 4, 5  # sub-step integrals of the flux and its square, mean coil voltage
M_ROWS = 6

__all__ = ["OUT_NAMES", "N_OUT", "LOGGED_NAMES", "N_LOGGED", "S_SIZE", "RING", "DRIVE_ROWS", "NOISE_ROWS", "run_chunk",
           "new_state"]


def new_state():
    """Zeroed kernel state: vector, play operators, ladder fluxes, delay rings (x, y)."""
    st = np.zeros(S_SIZE)
    st[S_TCONTACT] = -1.0
    return st, np.zeros((4, MAX_PLAY)), np.zeros((4, MAX_LADDER)), np.zeros((2, RING))


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def _phi1(x):
    """(1 - exp(-x))/x, stable near 0."""
    if abs(x) < 1e-2:
        return 1.0 - 0.5 * x + x * x / 6.0
    return -math.expm1(-x) / x


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def _exp_neg(x):
    """``exp(-x)`` for ``x >= 0``: Taylor polynomial of degree 10 in Estrin form for x < 0.5
    (relative error below 2e-11; a third of the latency of the library call), else ``math.exp``."""
    if x >= 0.5:
        return math.exp(-x)
    x2 = x * x
    x4 = x2 * x2
    x8 = x4 * x4
    p01 = 1.0 - x
    p23 = 0.5 - x * (1.0 / 6.0)
    p45 = (1.0 / 24.0) - x * (1.0 / 120.0)
    p67 = (1.0 / 720.0) - x * (1.0 / 5040.0)
    p89 = (1.0 / 40320.0) - x * (1.0 / 362880.0)
    return p01 + x2 * p23 + x4 * (p45 + x2 * p67) + x8 * (p89 + x2 * (1.0 / 3628800.0))


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def _disp(x, y, j):
    """Rotor displacement towards magnet j (ypos, yneg, xpos, xneg)."""
    if j == 0:
        return y
    if j == 1:
        return -y
    if j == 2:
        return x
    return -x


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def _segment(ph, v, f0, df, tau, n_den, r_den, ge, inv_den):
    r"""Advance one magnet's flux by ``tau`` at constant coil voltage ``v`` (no eddy currents,
    or the shorted-turn model).

    Exponential integrator of :math:`\dot\Phi = (N v - R\mathcal F_m(\Phi))/(N^2 + g_e R)`
    with the MMF linearised, :math:`\mathcal F_m \approx f_0 + \kappa(\Phi - \Phi_0)`:
    :math:`\Phi(\tau) = \Phi_0 + a\tau\,\varphi_1(b\tau)`, :math:`\varphi_1(x) = (1-e^{-x})/x`,
    :math:`a = (N v - R f_0)/(N^2 + g_e R)`, :math:`b = R\kappa/(N^2 + g_e R)`.
    If the current would reverse, the diodes block (i = 0) and the flux decays through the
    eddy path, :math:`g_e\dot\Phi = -\mathcal F_m` (or at once without one).

    Returns ``(Phi1, F1, blocked, int_Phi, int_Phi2, int_v)``.
    """
    a = n_den * v - r_den * f0
    b = r_den * df
    ph1 = ph + a * tau * _phi1(b * tau)
    f1 = f0 + df * (ph1 - ph)
    i1 = (ge * v) * inv_den + n_den * f1
    if i1 < 0.0:
        if ge > 0.0:
            ph1 = ph + (-f0 / ge) * tau * _phi1(df / ge * tau)
            f1 = f0 + df * (ph1 - ph)
        else:
            ph1 = ph - f0 / df
            f1 = 0.0
        blk = 1.0
        iv = (ph1 - ph) * (n_den / inv_den)
    else:
        blk = 0.0
        iv = v * tau
    i1p = 0.5 * tau * (ph + ph1)
    i2p = tau * (ph * ph + ph * ph1 + ph1 * ph1) / 3.0
    return ph1, f1, blk, i1p, i2p, iv


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def _segment_ladder(ph, v, f0, df, fe0, h, lad, j, p):
    r"""Advance one magnet by ``h`` at coil voltage ``v`` with the lamination ladder
    (:mod:`ssamb.sim.eddy`): :math:`N i = f_0 + \kappa(\Phi - \Phi_0) + \sum_k c_k(\Phi - \Psi_k)`,
    :math:`N\dot\Phi = v - R i`, :math:`\tau_k\dot\Psi_k = \Phi - \Psi_k`.

    Over the segment the flux is a ramp :math:`\Phi_0 + \rho t` whose slope takes the resistive
    drop trapezoidally, :math:`N\rho = v - R(i_0 + i_1)/2` (:math:`R i \ll v`); for a ramp the lagged
    fluxes are exact, :math:`\Psi_k(h) = \Phi(h) - \rho\tau_k + (\Psi_k - \Phi_0 + \rho\tau_k)e_k`,
    :math:`e_k = e^{-h/\tau_k}`, so the end eddy MMF is :math:`\rho A + B` with
    :math:`A = \sum_k c_k\tau_k(1 - e_k)`, :math:`B = \sum_k c_k(\Phi_0 - \Psi_k)e_k`, and the
    trapezoidal slope follows in closed form. If the current would reverse, the diodes block:
    i = 0 fixes :math:`\Phi` from the lagged fluxes, which relax towards it.
    Returns ``(Phi1, F1, Fe1, blocked, int_Phi, int_Phi2, int_v)``.
    """
    n = p[P_N]
    inv_n = p[P_INV_N]
    r = p[P_R]
    nlad = int(p[P_NLAD])
    e1 = _exp_neg(h * p[P_LAD_INVTAU])
    tk = p[P_LAD_TAU]
    ek = e1
    a_sum = 0.0
    b_sum = 0.0
    c_sum = 0.0
    for k in range(nlad):
        c = p[P_LAD_C0 + k]
        a_sum += c * tk * (1.0 - ek)
        b_sum += c * (ph - lad[j, k]) * ek
        c_sum += c
        tk *= 0.125
        ek *= ek
        ek *= ek
        ek *= ek
    i0 = (f0 + fe0) * inv_n
    if i0 < 0.0:
        i0 = 0.0
    g = (df * h + a_sum) * inv_n
    i_b = (f0 + b_sum) * inv_n
    rho = (v - 0.5 * r * (i0 + i_b)) / (n + 0.5 * r * g)
    if i_b + rho * g >= 0.0:
        tk = p[P_LAD_TAU]
        ek = e1
        for k in range(nlad):
            q = rho * tk
            lad[j, k] = ph - q + (lad[j, k] - ph + q) * ek + rho * h
            tk *= 0.125
            ek *= ek
            ek *= ek
            ek *= ek
        ph1 = ph + rho * h
        f1 = f0 + df * rho * h
        fe1 = rho * a_sum + b_sum
        blk = 0.0
        iv = v * h
    else:
        phc = ph - (f0 + fe0) / (df + c_sum)          # i = 0 with the lagged fluxes held
        fe_held = 0.0
        ek = e1
        for k in range(nlad):
            lad[j, k] = phc + (lad[j, k] - phc) * ek
            fe_held += p[P_LAD_C0 + k] * (ph - lad[j, k])
            ek *= ek
            ek *= ek
            ek *= ek
        ph1 = ph - (f0 + fe_held) / (df + c_sum)     # i = 0 with the relaxed lagged fluxes
        f1 = f0 + df * (ph1 - ph)
        fe1 = -f1
        blk = 1.0
        iv = n * (ph1 - ph)
    i1p = 0.5 * h * (ph + ph1)
    i2p = h * (ph * ph + ph * ph1 + ph1 * ph1) / 3.0
    return ph1, f1, fe1, blk, i1p, i2p, iv


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def _coil_i(blk, volt, f, fe, ge, vs, n, inv_den):
    r"""Coil current from the carried MMF ``f`` and eddy MMF ``fe``,
    :math:`(g_e v + N(\mathcal F_m + \mathcal F_{eddy}))/(g_e R + N^2)` (``inv_den``
    :math:`= 1/(g_e R + N^2)`); 0 while the diodes block."""
    if blk > 0.5:
        return 0.0
    i = (ge * volt * vs + n * (f + fe)) * inv_den
    return i if i > 0.0 else 0.0


@nb.njit(**_HOT)
def _eddy_mmf(st, lad, j, p):
    r"""Ladder eddy MMF of magnet j from its state, :math:`\sum_k c_k(\Phi - \Psi_k)`."""
    fe = 0.0
    ph = st[S_PHI + j]
    for k in range(int(p[P_NLAD])):
        fe += p[P_LAD_C0 + k] * (ph - lad[j, k])
    return fe


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=FASTMATH)
def _sym(j, k):
    """Index of entry (j, k) of a symmetric 4x4 matrix stored as its upper triangle (10 values)."""
    a = min(j, k)
    return 4 * a - (a * (a - 1)) // 2 + abs(k - j)


@nb.njit(**_HOT)
def _interp_q(qtab, p, x, y, qm):
    """Bilinear interpolation of the coupling tables at (x, y) into ``qm`` (30 values: the upper
    triangles of Q, dQ/dx, dQ/dy; see :func:`ssamb.sim.network.coupling_tables`)."""
    g = qtab.shape[0]
    half = p[P_QHALF]
    u = min(max((x + half) / (2.0 * half) * (g - 1), 0.0), g - 1.000001)
    w = min(max((y + half) / (2.0 * half) * (g - 1), 0.0), g - 1.000001)
    a = int(u)
    b = int(w)
    fu = u - a
    fw = w - b
    w00 = (1.0 - fu) * (1.0 - fw)
    w01 = (1.0 - fu) * fw
    w10 = fu * (1.0 - fw)
    w11 = fu * fw
    for e in range(qm.shape[0]):
        qm[e] = w00 * qtab[a, b, e] + w01 * qtab[a, b + 1, e] + w10 * qtab[a + 1, b, e] + w11 * qtab[a + 1, b + 1, e]


@nb.njit(**_HOT)
def _rotor_step(st, p, h, fmx, fmy, fext_x, fext_y):
    """Advance the rotor by ``h`` under the sub-step mean magnetic force, the weight share on
    this bearing (-y), the external force and the backup-bearing contact (penalty
    spring-damper on the radial penetration beyond the clearance, no tension);
    semi-implicit trapezoidal update."""
    st[S_FMX] = fmx
    st[S_FMY] = fmy
    if p[P_CLAMP] > 0.5:
        st[S_X] = p[P_CLAMP_X]
        st[S_Y] = p[P_CLAMP_Y]
        st[S_VX] = 0.0
        st[S_VY] = 0.0
        return
    m = p[P_MASS]
    x = st[S_X]
    y = st[S_Y]
    vx = st[S_VX]
    vy = st[S_VY]
    fx = fmx + fext_x
    fy = fmy + fext_y - m * p[P_GRAV]
    rr = math.sqrt(x * x + y * y)
    if rr > p[P_CLEAR]:
        inv_rr = 1.0 / rr
        pen = rr - p[P_CLEAR]
        vn = (x * vx + y * vy) * inv_rr
        fn = p[P_KC] * pen + p[P_CC] * vn
        if fn < 0.0:
            fn = 0.0
        fx -= fn * x * inv_rr
        fy -= fn * y * inv_rr
    hm = h * p[P_INV_MASS]
    vx1 = vx + fx * hm
    vy1 = vy + fy * hm
    st[S_X] = x + 0.5 * (vx + vx1) * h
    st[S_Y] = y + 0.5 * (vy + vy1) * h
    st[S_VX] = vx1
    st[S_VY] = vy1


@nb.njit(**_HOT)
def _mean_forces(p, mag, h, qm):
    r"""Sub-step mean magnetic force (Fx, Fy) from the flux integrals (rows ``M_S1``, ``M_S2`` of ``mag``).

    Series model: :math:`\Phi_j^2\cos\alpha/(\mu_0 A_p)` along each magnet's axis, exact in the
    mean of :math:`\Phi^2`. Network coupling (``XNET``): virtual work at constant flux,
    :math:`-\tfrac12\bar\Phi^T\partial Q/\partial(x, y)\bar\Phi` with the mean fluxes. The effect
    ``cross_coupling`` (coefficient c: a magnet's poles also carry c times each neighbour's flux,
    with alternating sign around the stator xpos -> ypos -> xneg -> yneg) uses the mean fluxes.
    """
    m1 = mag[M_S1]
    m2 = mag[M_S2]
    c = p[P_XCOUP]
    inv_h = 1.0 / h
    k = p[P_FORCE_K] * inv_h
    if c == 0.0:
        fy = k * (m2[0] - m2[1])
        fx = k * (m2[2] - m2[3])
    else:
        e0 = c * (m1[2] - m1[3])
        e1 = c * (m1[3] - m1[2])
        e2 = c * (m1[0] - m1[1])
        e3 = c * (m1[1] - m1[0])
        q0 = m2[0] + (2.0 * m1[0] * e0 + e0 * e0) * inv_h
        q1 = m2[1] + (2.0 * m1[1] * e1 + e1 * e1) * inv_h
        q2 = m2[2] + (2.0 * m1[2] * e2 + e2 * e2) * inv_h
        q3 = m2[3] + (2.0 * m1[3] * e3 + e3 * e3) * inv_h
        fx, fy = k * (q2 - q3), k * (q0 - q1)
    if p[P_XNET] > 0.5:
        inv_h2 = inv_h * inv_h
        for r in range(4):
            for s in range(r, 4):
                e = _sym(r, s)
                mm = (0.5 if r == s else 1.0) * m1[r] * m1[s] * inv_h2
                fx -= qm[10 + e] * mm
                fy -= qm[20 + e] * mm
    return fx, fy


@nb.njit(**_HOT)
def _pi_update(st, p, j, i_meas):
    """Amplifier PI at a period start: duty from the sampled current, conditional integration."""
    e = st[S_IREF + j] - i_meas
    integ_old = st[S_INTEG + j]
    integ = integ_old + p[P_KI_PA] * e
    dty = 0.5 + p[P_KP_PA] * e + integ
    if dty > p[P_DMAX]:
        dty = p[P_DMAX]
        if e > 0.0:
            integ = integ_old
    elif dty < p[P_DMIN]:
        dty = p[P_DMIN]
        if e < 0.0:
            integ = integ_old
    st[S_INTEG + j] = integ
    st[S_DUTY + j] = dty
    return dty


@nb.njit(inline="always", **_HOT)
def _advance_magnet(st, p, j, t_a, t_b, mag, lad, npi, rip, rip_n, track, n_den, r_den, ge, inv_den):
    r"""Integrate magnet ``j`` (flux and amplifier ``j``) from ``t_a`` to ``t_b``.

    Every PWM event of the amplifier inside the interval is an exact breakpoint: the turn-on
    edge (:math:`v = +V`), the turn-off edge (:math:`v = -V`) and the period start, where the PI
    loop samples the current (through the converter: noise ``npi[j, period]`` and
    quantisation), sets the duty cycle :math:`D` and thereby the next edges
    :math:`t_s + (1 \mp D)T/2` (+ the dead time before turn-on). Between breakpoints
    :func:`_segment` (or :func:`_segment_ladder`) integrates the flux.

    With ``track`` (ypos only) the ripple extremes of the current period are updated after every
    segment and edge; at every ypos period start the finished period's (start, max, min) is
    appended to ``rip``. Returns ``(rip_n, int_Phi, int_Phi2, int_v, int_v_commanded)``.
    """
    T = p[P_TPWM]
    vs = p[P_V]
    n = p[P_N]
    ladder = p[P_NLAD] > 0.5
    ph = st[S_PHI + j]
    volt = st[S_VOLT + j]
    phase = st[S_PHASE + j]
    t_on = st[S_TON + j]
    t_off = st[S_TOFF + j]
    mper = st[S_M + j]
    blk = st[S_BLK + j]
    f = mag[M_F, j]
    fe = mag[M_FE, j]
    df = mag[M_DF, j]
    tr = track and j == 0
    rmax = st[S_RIPMAX]
    rmin = st[S_RIPMIN]
    s1 = 0.0
    s2 = 0.0
    sv = 0.0
    scmd = 0.0
    t_cur = t_a
    while True:
        # pending event: turn-on edge, turn-off edge or the next period start
        if phase < 0.5:
            te = t_on
        elif phase < 1.5:
            te = t_off
        else:
            te = (mper + 1.0) * T
        last = te > t_b
        t_seg = t_b if last else te
        if t_seg > t_cur:
            if ladder:
                ph, f, fe, blk, a1, a2, a3 = _segment_ladder(ph, volt * vs, f, df, fe, t_seg - t_cur, lad, j, p)
            else:
                ph, f, blk, a1, a2, a3 = _segment(ph, volt * vs, f, df, t_seg - t_cur, n_den, r_den, ge, inv_den)
            s1 += a1
            s2 += a2
            sv += a3
            scmd += volt * vs * (t_seg - t_cur)
            t_cur = t_seg
            if tr:
                i0 = _coil_i(blk, volt, f, fe, ge, vs, n, inv_den)
                rmax = max(rmax, i0)
                rmin = min(rmin, i0)
        if last:
            break
        if phase < 0.5:                   # turn-on edge
            volt = 1.0
            phase = 1.0
        elif phase < 1.5:                 # turn-off edge
            volt = -1.0
            phase = 2.0
        else:                             # period start: PI update on the sampled (average) current
            mper += 1.0
            ts = mper * T
            volt = -1.0
            i_true = _coil_i(blk, volt, f, fe, ge, vs, n, inv_den)
            m_idx = min(int(mper), npi.shape[1] - 1)
            i_meas = adc(i_true + npi[j, m_idx], p[P_I_Q], p[P_I_INVQ], p[P_I_CMAX])
            dty = _pi_update(st, p, j, i_meas)
            t_on = ts + (1.0 - dty) * T / 2.0 + p[P_DEADTIME]
            t_off = ts + (1.0 + dty) * T / 2.0
            phase = 0.0 if t_on < t_off else 2.0
            if j == 0:
                # close the ripple record of the finished period of the ypos amplifier
                if st[S_RIPN] > 0.5 and rip_n < rip.shape[1]:
                    rip[0, rip_n] = ts - T
                    rip[1, rip_n] = rmax
                    rip[2, rip_n] = rmin
                    rip_n += 1
                rmax = i_true
                rmin = i_true
                st[S_RIPN] = 1.0
        if tr:
            i0 = _coil_i(blk, volt, f, fe, ge, vs, n, inv_den)
            rmax = max(rmax, i0)
            rmin = min(rmin, i0)
    st[S_PHI + j] = ph
    st[S_VOLT + j] = volt
    st[S_PHASE + j] = phase
    st[S_TON + j] = t_on
    st[S_TOFF + j] = t_off
    st[S_M + j] = mper
    st[S_BLK + j] = blk
    mag[M_F, j] = f
    mag[M_FE, j] = fe
    if j == 0:
        st[S_RIPMAX] = rmax
        st[S_RIPMIN] = rmin
    return rip_n, s1, s2, sv, scmd


@nb.njit(**_HOT)
def _advance_magnets(st, p, t_a, t_b, mag, lad, npi, rip, rip_n, track, n_den, r_den, ge, inv_den, inv_h):
    """:func:`_advance_magnet` for the four magnets over one sub-step ``[t_a, t_b]``.

    Stores each magnet's flux integrals and mean coil voltage (``inv_h`` = 1/h) in the rows
    ``M_S1``, ``M_S2``, ``M_VBAR`` of ``mag``. One call per sub-step with :func:`_advance_magnet`
    inlined in its loop, and the magnets' values in one work array: a call per magnet, each
    passing a dozen arrays, took a fifth of the kernel time. Returns ``(rip_n, volt-seconds
    commanded to ypos)``.
    """
    scmd_ypos = 0.0
    for j in range(4):
        rip_n, mag[M_S1, j], mag[M_S2, j], sv, scmd = _advance_magnet(st, p, j, t_a, t_b, mag, lad, npi, rip,
                                                                      rip_n, track, n_den, r_den, ge, inv_den)
        mag[M_VBAR, j] = sv * inv_h
        if j == 0:
            scmd_ypos = scmd
    return rip_n, scmd_ypos


@nb.njit(**_HOT)
def _delayed(ring, n, delay_samples):
    """Value ``delay_samples`` (fractional) samples ago by linear interpolation."""
    m = int(math.floor(delay_samples))
    fr = delay_samples - m
    newest = n - 1
    i0 = newest - m
    i1 = i0 - 1
    if i0 < 0:
        i0 = 0
    if i1 < 0:
        i1 = 0
    return (1.0 - fr) * ring[i0 % RING] + fr * ring[i1 % RING]


@nb.njit(**_HOT)
def _magnet_mmfs(st, p, z, qtab, mag, qm):
    """Exact MMF and its slope of every magnet at the sample, plus the network coupling
    :math:`Q\\Phi` (``XNET``; ``qm`` receives Q and its gradient). The eddy MMF is carried from
    the integration (exact: a function of the fluxes and lagged fluxes)."""
    for j in range(4):
        gs = gap_sum(_disp(st[S_X], st[S_Y], j), p)
        f, df = mmf_update(st[S_PHI + j], gs, z, j, p)
        mag[M_F, j] = f
        mag[M_DF, j] = df
    if p[P_XNET] > 0.5:
        _interp_q(qtab, p, st[S_X], st[S_Y], qm)
        for j in range(4):
            off = 0.0
            for k in range(4):
                off += qm[_sym(j, k)] * st[S_PHI + k]
            mag[M_F, j] += off
            mag[M_DF, j] += qm[_sym(j, j)]


@nb.njit(**_HOT)
def _control(st, p, ss, rings, k, fs, x_sens, drive, noise_y):
    """Self-sensed y, sensor effects, PID and the current references (computation delay)."""
    if p[P_SS_IDEAL] > 0.5:    # ideal y sensor instead of DCM (diagnostics)
        y_ss = p[P_GAIN_Y] * adc(st[S_Y] + noise_y, p[P_X_Q], p[P_X_INVQ], p[P_X_CMAX])
    else:
        y_ss = p[P_GAIN_Y] * ss[D_OUT]
    dn = int(st[S_DN])
    rings[0, dn % RING] = x_sens
    rings[1, dn % RING] = y_ss
    dn += 1
    st[S_DN] = dn
    x_ctl = _delayed(rings[0], dn, p[P_DELAY_X] * fs)
    y_ctl = _delayed(rings[1], dn, p[P_DELAY_Y] * fs)
    ux = 0.0
    uy = 0.0
    if p[P_PID_ON] > 0.5:
        ux = pid_step(st, p, S_PIDX_I, drive[0, k] - x_ctl)
        uy = pid_step(st, p, S_PIDY_I, drive[1, k] - y_ctl)
    st[S_UX] = ux
    st[S_UY] = uy
    cx = ux + drive[2, k]
    cy = uy + drive[3, k]
    ib = p[P_IBIAS]
    for j in range(4):
        c = cy if j < 2 else cx
        rj = ib + c if j % 2 == 0 else ib - c
        rj = min(max(rj, 0.0), p[P_IREF_MAX])
        if p[P_CDELAY] > 0.5:
            st[S_IREF + j] = st[S_IREFN + j]
            st[S_IREFN + j] = rj
        else:
            st[S_IREF + j] = rj
    return x_ctl, y_ctl


@nb.njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def run_chunk(p, st, ss, z, lad, rings, ss_rings, tb, qtab, k0, k1, drive, noise, npi, out, fine, rip, rip_n):
    """Simulate controller samples ``k0 .. k1-1`` in place; returns the updated ripple count.

    ``drive`` (rows :data:`DRIVE_ROWS`) holds the references, injections and external forces,
    ``noise`` (rows :data:`NOISE_ROWS`) the analog noise of the converters at every sample and
    ``npi`` (4 x periods) that of the amplifiers' PI samples. ``out`` (N_OUT x n) receives one
    row per sample (an ``out`` of N_LOGGED rows the rows :data:`LOGGED_NAMES`: the true states
    are not recorded); ``fine`` (13 x n*substeps, or 0 columns) receives (t, four currents, four
    fluxes, four mean coil voltages over the sub-step) at every sub-step end; ``rip``
    (3 x n_periods) receives (period start, max, min) of the ypos current in every PWM period.
    """
    fs = p[P_FS]
    dt = 1.0 / fs
    nsub = int(p[P_SUBSTEPS])
    h = dt / nsub
    inv_h = 1.0 / h
    axs = -math.expm1(-p[P_XS_BW] * h)
    record_fine = fine.shape[1] > 0
    states = out.shape[0] == N_OUT
    track = rip.shape[1] > 0
    isamp = np.empty(4)
    n_turns = p[P_N]
    ge = p[P_GE]
    inv_den = 1.0 / (n_turns * n_turns + ge * p[P_R])
    n_den = n_turns * inv_den
    r_den = p[P_R] * inv_den
    vs = p[P_V]
    mag = np.zeros((M_ROWS, 4))
    for j in range(4):
        mag[M_FE, j] = _eddy_mmf(st, lad, j, p)
    qm = np.zeros(30)
    ring_i, ring_l, win = ss_rings[0], ss_rings[1], ss_rings[2]   # views made once (no refcounts per sample)
    for k in range(k0, k1):
        t = k * dt
        _magnet_mmfs(st, p, z, qtab, mag, qm)
        # ---------------- converters of the DSP ----------------
        for j in range(4):
            i_true = _coil_i(st[S_BLK + j], st[S_VOLT + j], mag[M_F, j], mag[M_FE, j], ge, vs, n_turns, inv_den)
            isamp[j] = adc(i_true + noise[2 + j, k], p[P_I_Q], p[P_I_INVQ], p[P_I_CMAX])
        x_sens = adc(p[P_GAIN_X] * st[S_XS] + noise[0, k], p[P_X_Q], p[P_X_INVQ], p[P_X_CMAX])
        dcm_update(ss, p, ring_i, ring_l, win, isamp[0], tb)
        x_ctl, y_ctl = _control(st, p, ss, rings, k, fs, x_sens, drive, noise[1, k])
        # ---------------- record ----------------
        out[O_T, k] = t
        out[O_XM, k] = x_ctl
        out[O_YM, k] = adc(st[S_Y] + noise[1, k], p[P_X_Q], p[P_X_INVQ], p[P_X_CMAX])
        out[O_YSS, k] = y_ctl
        for j in range(4):
            out[O_I + j, k] = isamp[j]
        out[O_UX, k] = st[S_UX]
        out[O_UY, k] = st[S_UY]
        rr = math.sqrt(st[S_X] ** 2 + st[S_Y] ** 2)
        contact = 1.0 if rr >= p[P_CLEAR] else 0.0
        if rr >= p[P_CLEAR] and st[S_TCONTACT] < 0.0:
            st[S_TCONTACT] = t
        if states:
            for j in range(4):
                out[O_B + j, k] = st[S_PHI + j] * p[P_INV_AP]
                out[O_D + j, k] = st[S_DUTY + j]
            out[O_XT, k] = st[S_X]
            out[O_YT, k] = st[S_Y]
            out[O_CONTACT, k] = contact
            out[O_FMX, k] = st[S_FMX]
            out[O_FMY, k] = st[S_FMY]
            out[O_YSSRAW, k] = ss[D_RAW]
            out[O_VX, k] = st[S_VX]
            out[O_VY, k] = st[S_VY]
        else:
            out[L_CONTACT, k] = contact
            out[L_YSSRAW, k] = ss[D_RAW]
        # ---------------- integrate to t_{k+1} ----------------
        for s in range(nsub):
            t_a = (k + s / nsub) * dt
            t_b = (k + (s + 1.0) / nsub) * dt
            rip_n, scmd = _advance_magnets(st, p, t_a, t_b, mag, lad, npi, rip, rip_n, track, n_den, r_den, ge,
                                           inv_den, inv_h)
            ss[D_LAM] += scmd
            fmx, fmy = _mean_forces(p, mag, h, qm)
            _rotor_step(st, p, h, fmx, fmy, drive[4, k], drive[5, k])
            # x probe: first-order low-pass of the true position
            st[S_XS] += axs * (st[S_X] - st[S_XS])
            if record_fine:
                col = k * nsub + s
                fine[0, col] = t_b
                for j in range(4):
                    fine[1 + j, col] = _coil_i(st[S_BLK + j], st[S_VOLT + j], mag[M_F, j], mag[M_FE, j], ge, vs,
                                               n_turns, inv_den)
                    fine[5 + j, col] = st[S_PHI + j]
                    fine[9 + j, col] = mag[M_VBAR, j]
    return rip_n
