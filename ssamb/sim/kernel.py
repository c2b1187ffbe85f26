r"""The compiled simulation kernel: event-exact PWM, magnetics, rotor, control, DCM self-sensing.

Time is organised around the controller samples :math:`t_k = k/f_s` (83.3 kHz). At each
sample the kernel

1. samples the sensors: the x eddy-current probe (first-order bandwidth), the four coil
   currents (instantaneous, with ripple), the true y for evaluation;
2. runs DCM self-sensing on the ypos current (:func:`_dcm_update`);
3. applies the sensor effects (gain, transport delay) and runs the two discrete PID
   controllers, which set the current references :math:`i_0 \pm u + \text{inj}`;
4. records one row of outputs;
5. integrates to :math:`t_{k+1}` in ``substeps`` sub-steps. Inside a sub-step every PWM event
   (period start with the PI update, turn-on edge, turn-off edge) is an exact breakpoint,
   so the switching edges -- and therefore the ripple peaks -- are resolved exactly; between
   breakpoints the coil voltage is constant and each magnet's flux ODE
   :math:`\dot\Phi = (N v - R\mathcal F_m(\Phi))/(N^2 + g_e R)` is integrated exactly for its
   linearisation about the segment start (exponential integrator), the rotor with the
   trapezoidal force average.

Amplifiers (two-state, paper section 2.2): centre-aligned PWM of period :math:`T`; the coil sees
:math:`+V` during :math:`[t_s + (1-D)T/2 + t_{dead},\ t_s + (1+D)T/2]` and :math:`-V` otherwise
(freewheeling through the diodes back into the supply). At every period start the PI loop
samples the current (the middle of the :math:`-V` interval, i.e. the ripple average) and sets
:math:`D = 1/2 + K_P e + \sum K_I e` clipped to ``[duty_min, duty_max]`` with conditional
integration. The diodes forbid negative current: when a step would reverse it, the coil is
open (i = 0) and the flux decays through the eddy path.

Effects of the close-the-loop library act here as parameters (``DELAY_X/Y`` sensor transport
delay, ``GAIN_X/Y`` sensor scale error, ``DEADTIME`` turn-on delay of every PWM pulse, ``XCOUP``
flux coupling between adjacent magnets) or as the external force arrays (static load,
unbalance, arbitrary forces).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from .magnetics import MAX_PLAY, NO_NRT, gap_sum, mmf_update
from .params import (MU0, P_AP, P_CC, P_CLAMP, P_CLAMP_X, P_CLAMP_Y, P_CLEAR, P_COSA,
                     P_DEADTIME, P_DELAY_X, P_DELAY_Y, P_DMAX, P_DMIN, P_FS, P_G0, P_GAIN_X,
                     P_GAIN_Y, P_GE, P_GRAV, P_IBIAS, P_IREF_MAX, P_KC, P_KI_PA, P_KP_PA, P_LEQ,
                     P_MASS, P_MUR, P_N, P_PID_AD, P_PID_BD, P_PID_KI_HALF, P_PID_KP, P_PID_ON,
                     P_R, P_SS_ALPHA, P_SS_IDEAL, P_SS_ORDER, P_SS_POLY, P_SS_GATE, P_SS_GAIN, P_SS_MIN_DD, P_SS_OFF, P_SS_W, P_SUBSTEPS,
                     P_TPWM, P_UMAX, P_V, P_XCOUP, P_XS_BW)

# numba's on-disk cache (cache=True) is keyed on the content of this file only: after changing
# params.py (the P_* layout) or a compiled helper imported from another module, change this
# file too (or clear __pycache__), or stale machine code with old constants is reused.

# helpers called every sample: no numba runtime (see magnetics.NO_NRT), no allocation
_HOT = dict(cache=True, error_model="numpy", fastmath=True, **NO_NRT)

# ---- state vector indices ------------------------------------------------------------------
S_PHI = 0            # 4 fluxes (Wb): ypos, yneg, xpos, xneg
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
S_IREF = 49          # 4 current references
S_SSLP = 53          # DCM low-pass state (m)
S_SSN = 54           # DCM samples pushed
S_TCONTACT = 55      # first contact time (s), -1 if none
S_RIPMAX, S_RIPMIN, S_RIPN = 56, 57, 58   # ypos ripple tracker in the current period
S_YSSRAW = 59
S_DN = 60            # delay-buffer samples pushed
S_FMX, S_FMY = 61, 62
S_SSF = 64           # 4 DCM low-pass stages (m); the output is the last active stage
S_SSREJ = 68         # DCM windows rejected by the residual gate
S_SIZE = 72

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
RING = 256           # delay-buffer length (samples): up to 3 ms of transport delay
SS_RING = 64         # DCM window buffer length

__all__ = ["OUT_NAMES", "N_OUT", "S_SIZE", "RING", "SS_RING", "run_chunk", "new_state", "trend_basis"]


def trend_basis(window: int, order: int) -> np.ndarray:
    """Discrete orthonormal polynomial basis (order+1 rows, ``window`` columns) for the DCM trend.

    Rows span the polynomials of degree <= ``order`` on the sample indices of the window and
    are orthonormal (QR of the Vandermonde matrix), so projecting them out is a few dot products.
    """
    tn = np.linspace(-1.0, 1.0, window)
    v = np.vander(tn, order + 1, increasing=True)
    qm, _ = np.linalg.qr(v)
    return np.ascontiguousarray(qm.T)


def new_state():
    """Zeroed state vector, play-operator states, and ring buffers."""
    st = np.zeros(S_SIZE)
    st[S_TCONTACT] = -1.0
    z = np.zeros((4, MAX_PLAY))
    ring_i = np.zeros(SS_RING)
    ring_d = np.zeros(SS_RING)
    ring_s = np.zeros(SS_RING)
    ring_x = np.zeros(RING)
    ring_y = np.zeros(RING)
    return st, z, ring_i, ring_d, ring_s, ring_x, ring_y


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=True)
def _phi1(x):
    """(1 - exp(-x))/x, stable near 0."""
    if abs(x) < 1e-2:
        return 1.0 - 0.5 * x + x * x / 6.0
    return -math.expm1(-x) / x


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=True)
def _disp(x, y, j):
    """Rotor displacement towards magnet j (ypos, yneg, xpos, xneg)."""
    if j == 0:
        return y
    if j == 1:
        return -y
    if j == 2:
        return x
    return -x


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=True)
def _segment(ph, v, f0, df, tau, n_den, r_den, ge, inv_den):
    r"""Advance one magnet's flux by ``tau`` at constant coil voltage ``v``.

    Exponential integrator of :math:`\dot\Phi = (N v - R\mathcal F_m(\Phi))/(N^2 + g_e R)`
    with the MMF linearised, :math:`\mathcal F_m \approx f_0 + \kappa(\Phi - \Phi_0)`, where
    ``f0`` and ``df`` are the MMF and the differential reluctance :math:`\kappa`
    (evaluated exactly once per controller sample and carried along the segments linearly):
    :math:`\Phi(\tau) = \Phi_0 + a\tau\,\varphi_1(b\tau)`, :math:`\varphi_1(x) = (1-e^{-x})/x`,
    :math:`a = (N v - R f_0)/(N^2 + g_e R)`, :math:`b = R\kappa/(N^2 + g_e R)`.
    If the current would reverse, the diodes block (i = 0) and the flux decays through the
    eddy path, :math:`g_e\dot\Phi = -\mathcal F_m`.

    Returns ``(Phi1, F1, blocked, int_Phi, int_Phi2, int_v)``: the flux and carried MMF at the
    segment end, the diode flag (1.0 if blocked), and :math:`\int\Phi\,dt`,
    :math:`\int\Phi^2 dt` (exact for a linear ramp) and :math:`\int v\,dt` over the segment
    (an open coil's voltage is whatever keeps i = 0, :math:`v = N\dot\Phi`).
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


@nb.njit(cache=True, inline="always", error_model="numpy", fastmath=True)
def _coil_i(blk, volt, f, ge, vs, n, den):
    r"""Coil current from the carried MMF, :math:`(g_e v + N\mathcal F_m)/(g_e R + N^2)`
    (``den`` :math:`= g_e R + N^2`); 0 while the diodes block."""
    if blk > 0.5:
        return 0.0
    i = (ge * volt * vs + n * f) / den
    return i if i > 0.0 else 0.0


@nb.njit(**_HOT)
def _rotor_step(st, p, h, fmx, fmy, fext_x, fext_y):
    """Advance the rotor by ``h`` under the sub-step mean magnetic force, gravity (-y), the
    external force and the backup-bearing contact (penalty spring-damper on the radial
    penetration beyond the clearance); semi-implicit trapezoidal update."""
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
        pen = rr - p[P_CLEAR]
        vn = (x * vx + y * vy) / rr
        fn = p[P_KC] * pen + p[P_CC] * vn
        if fn < 0.0:
            fn = 0.0
        fx -= fn * x / rr
        fy -= fn * y / rr
    vx1 = vx + fx / m * h
    vy1 = vy + fy / m * h
    st[S_X] = x + 0.5 * (vx + vx1) * h
    st[S_Y] = y + 0.5 * (vy + vy1) * h
    st[S_VX] = vx1
    st[S_VY] = vy1


@nb.njit(**_HOT)
def _mean_forces(p, m1, m2, h):
    r"""Sub-step mean magnetic force (Fx, Fy) from the flux integrals.

    Without coupling the mean of :math:`\Phi^2` is exact; the coupling terms of the effect
    ``cross_coupling`` (coefficient c: a magnet's poles also carry c times each neighbour's
    flux, with alternating sign around the stator xpos -> ypos -> xneg -> yneg) use the mean
    fluxes.
    """
    c = p[P_XCOUP]
    k = p[P_COSA] / (MU0 * p[P_AP]) / h
    if c == 0.0:
        fy = k * (m2[0] - m2[1])
        fx = k * (m2[2] - m2[3])
        return fx, fy
    e0 = c * (m1[2] - m1[3])
    e1 = c * (m1[3] - m1[2])
    e2 = c * (m1[0] - m1[1])
    e3 = c * (m1[1] - m1[0])
    q0 = m2[0] + 2.0 * m1[0] * e0 / h + e0 * e0 / h
    q1 = m2[1] + 2.0 * m1[1] * e1 / h + e1 * e1 / h
    q2 = m2[2] + 2.0 * m1[2] * e2 / h + e2 * e2 / h
    q3 = m2[3] + 2.0 * m1[3] * e3 / h + e3 * e3 / h
    return k * (q2 - q3), k * (q0 - q1)


@nb.njit(**_HOT)
def _advance_magnet(st, p, j, t_a, t_b, fm, dfm, rip, rip_n, track, n_den, r_den, ge, inv_den):
    r"""Integrate magnet ``j`` (flux and amplifier ``j``) from ``t_a`` to ``t_b``.

    Every PWM event of the amplifier inside the interval is an exact breakpoint: the turn-on
    edge (:math:`v = +V`), the turn-off edge (:math:`v = -V`) and the period start, where the PI
    loop samples the current, sets the duty cycle :math:`D` and thereby the next edges
    :math:`t_s + (1 \mp D)T/2` (+ the dead time before turn-on). Between breakpoints
    :func:`_segment` integrates the flux exactly for the linearised MMF.

    The magnet's state is read from ``st`` once, kept in local variables through the event
    loop and written back at the end. With ``track`` (ypos only) the ripple extremes of the
    current period are updated after every segment and edge; at every ypos period start the
    finished period's (start, max, min) is appended to ``rip``.

    Returns ``(rip_n, int_Phi, int_Phi2, int_v)`` over the interval.
    """
    T = p[P_TPWM]
    vs = p[P_V]
    n = p[P_N]
    den = ge * p[P_R] + n * n
    ph = st[S_PHI + j]
    volt = st[S_VOLT + j]
    phase = st[S_PHASE + j]
    t_on = st[S_TON + j]
    t_off = st[S_TOFF + j]
    mper = st[S_M + j]
    blk = st[S_BLK + j]
    f = fm[j]
    df = dfm[j]
    tr = track and j == 0
    rmax = st[S_RIPMAX]
    rmin = st[S_RIPMIN]
    s1 = 0.0
    s2 = 0.0
    sv = 0.0
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
            ph, f, blk, a1, a2, a3 = _segment(ph, volt * vs, f, df, t_seg - t_cur,
                                              n_den, r_den, ge, inv_den)
            s1 += a1
            s2 += a2
            sv += a3
            t_cur = t_seg
            if tr:
                i0 = _coil_i(blk, volt, f, ge, vs, n, den)
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
            i_meas = _coil_i(blk, volt, f, ge, vs, n, den)
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
                rmax = i_meas
                rmin = i_meas
                st[S_RIPN] = 1.0
        if tr:
            i0 = _coil_i(blk, volt, f, ge, vs, n, den)
            rmax = max(rmax, i0)
            rmin = min(rmin, i0)
    st[S_PHI + j] = ph
    st[S_VOLT + j] = volt
    st[S_PHASE + j] = phase
    st[S_TON + j] = t_on
    st[S_TOFF + j] = t_off
    st[S_M + j] = mper
    st[S_BLK + j] = blk
    fm[j] = f
    if j == 0:
        st[S_RIPMAX] = rmax
        st[S_RIPMIN] = rmin
    return rip_n, s1, s2, sv


@nb.njit(cache=True, error_model="numpy", fastmath=True)
def _ripple_shape(t, t_on, t_off, T):
    r"""Normalised two-state PWM ripple at time ``t`` of a period whose coil voltage is +V on
    ``[t_on, t_off]`` and -V elsewhere: -1 at the turn-on edge, +1 at the turn-off edge, linear
    in between (rising over the on-time, falling over the off-time ``T - (t_off - t_on)``)."""
    on = t_off - t_on
    off = T - on
    if on <= 0.0 or off <= 0.0:
        return 0.0
    if t < t_on:
        return 1.0 - 2.0 * (t - (t_off - T)) / off
    if t <= t_off:
        return -1.0 + 2.0 * (t - t_on) / on
    return 1.0 - 2.0 * (t - t_off) / off


@nb.njit(**_HOT)
def _dcm_update(st, p, ring_i, ring_q, ring_s, i_samp, t, tb):
    r"""DCM self-sensing (paper section 2.1, eq. (2)) on one new ypos current sample.

    The DSP knows its PWM timer, so every current sample's position in the switching cycle is
    known. Over the last W samples (``selfsensing.window_samples``; 25 samples = 9.0 PWM
    periods whose ripple phases are spread uniformly because 25 x 30/83.3 = 9.004) the current
    is modelled as

    .. math:: i_k = c_0 + c_1 (t_k - \bar t) + \frac{V T}{L} q_k + b\,\sigma_k,

    * :math:`c_0 + c_1 t`: the slow (control) current, removed as a local trend;
    * :math:`q_k = D_k(1-D_k) s_k` with :math:`s_k \in [-1, 1]` the normalised triangular
      ripple (-1 at the turn-on edge, +1 at the turn-off edge): the two-state ripple is
      :math:`\Delta i = 2 V D (1-D) T/L`, so its peak :math:`\Delta i/2 = (VT/L) D(1-D)` --
      the duty compensation;
    * :math:`\sigma_k = \pm 1 - (2D_k - 1)`: the square wave in phase with the coil voltage that
      the eddy-current path adds at every edge (nuisance parameter :math:`b`).

    The least-squares estimate of :math:`1/L` (i.e. of the peak ripple per unit duty factor)
    gives the airgap by eq. (2): :math:`2 g = \mu_0 N^2 A_p / L - l_{eq}/\mu_r`,
    :math:`y = (2 g_0 - 2 g)/(2\cos\alpha)`; it is calibrated (gain, offset) and low-passed by
    ``SS_ORDER`` cascaded first-order sections. A window whose regressors are degenerate (an
    amplifier saturated at D = 0 or 1 has no ripple) holds the last estimate.

    The literal maximum operator (max - min of the samples) was tried first and rejected: with
    2.78 samples per switching period it misses the peak by up to 2 % of the ripple, and with
    the eddy-current step at each edge its error reached 140 um rms, which the PID derivative
    turned into current-saturating feedback (see the simulator notes in the README).

    Gate: if the rms fit residual exceeds ``SS_GATE`` times the fitted ripple peak (a current
    step or an amplifier saturating inside the window) the window is rejected and the last
    estimate held (counted in the state ``S_SSREJ``).
    """
    T = p[P_TPWM]
    ts = st[S_M] * T
    # the DSP knows its PWM timer, including the dead time it inserts before every turn-on
    t_on = ts + (1.0 - st[S_DUTY]) * T / 2.0 + p[P_DEADTIME]
    t_off = ts + (1.0 + st[S_DUTY]) * T / 2.0
    dty = (t_off - t_on) / T
    if dty < 0.0:
        dty = 0.0
    w = int(p[P_SS_W])
    nidx = int(st[S_SSN])
    slot = nidx % SS_RING
    ring_i[slot] = i_samp
    ring_q[slot] = dty * (1.0 - dty) * _ripple_shape(t, t_on, t_off, T)
    on = 1.0 if (t >= t_on and t <= t_off) else -1.0
    ring_s[slot] = on - (2.0 * dty - 1.0)
    nidx += 1
    st[S_SSN] = nidx
    if nidx < w:
        return
    # Least squares with the trend eliminated by projection onto an orthonormal polynomial basis
    # ``tb`` (npoly x W, discrete orthonormal polynomials, see trend_basis()):
    # x~ = x - tb' (tb x); inner products of projected vectors follow from the raw ones.
    npoly = tb.shape[0]
    first = nidx - w              # ring index of the oldest sample in the window (>= 0)
    sqq = 0.0
    sqs = 0.0
    sss = 0.0
    sqi = 0.0
    ssi = 0.0
    sii = 0.0
    for q in range(w):
        idx = (first + q) % SS_RING
        qq = ring_q[idx]
        sg = ring_s[idx]
        ii = ring_i[idx]
        sqq += qq * qq
        sqs += qq * sg
        sss += sg * sg
        sqi += qq * ii
        ssi += sg * ii
        sii += ii * ii
    for m in range(npoly):
        tq = 0.0
        tsg = 0.0
        ti = 0.0
        for q in range(w):
            idx = (first + q) % SS_RING
            bm = tb[m, q]
            tq += bm * ring_q[idx]
            tsg += bm * ring_s[idx]
            ti += bm * ring_i[idx]
        sqq -= tq * tq
        sqs -= tq * tsg
        sss -= tsg * tsg
        sqi -= tq * ti
        ssi -= tsg * ti
        sii -= ti * ti
    # degenerate window (no ripple: amplifier saturated): hold
    if sqq < p[P_SS_MIN_DD] * 1e-3 * w:
        return
    det = sqq * sss - sqs * sqs
    if det <= 1e-10 * sqq * sss:
        return
    a_l = (sqi * sss - ssi * sqs) / det
    b_sq = (ssi * sqq - sqi * sqs) / det
    if a_l <= 0.0:
        return
    # gate: a window the ripple model does not explain (a current step, the amplifier saturating
    # inside the window) is rejected and the last estimate held
    rss = sii - a_l * sqi - b_sq * ssi
    rms = math.sqrt(max(rss, 0.0) / w)
    if rms > p[P_SS_GATE] * a_l * dty * (1.0 - dty):
        st[S_SSREJ] += 1.0
        return
    inv_l = a_l / (p[P_V] * T)
    n = p[P_N]
    g2 = MU0 * n * n * p[P_AP] * inv_l - p[P_LEQ] / p[P_MUR]
    y_raw = (2.0 * p[P_G0] - g2) / (2.0 * p[P_COSA])
    st[S_YSSRAW] = y_raw
    y_cal = p[P_SS_GAIN] * y_raw + p[P_SS_OFF]
    nord = int(p[P_SS_ORDER])
    u = y_cal
    for q in range(nord):
        st[S_SSF + q] += p[P_SS_ALPHA] * (u - st[S_SSF + q])
        u = st[S_SSF + q]
    st[S_SSLP] = u


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
def _pid(st, p, base, e):
    """Tustin PID: u = Kp e + I + D (state: I, D, previous error at st[base..base+2])."""
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


@nb.njit(cache=True, error_model="numpy", fastmath=True)
def run_chunk(p, st, z, ring_i, ring_d, ring_s, ring_x, ring_y, tb, k0, k1,
              r_x, r_y, inj_x, inj_y, f_x, f_y, n_x, n_ym, n_i,
              out, fine, rip, rip_n):
    """Simulate controller samples ``k0 .. k1-1`` in place; returns the updated ripple count.

    ``out`` (N_OUT x n) receives one row per sample; ``fine`` (13 x n*substeps, or 0 columns)
    receives (t, four currents, four fluxes, four mean coil voltages over the sub-step) at
    every sub-step end; ``rip`` (3 x n_periods) receives
    (period start, max, min) of the ypos current in every PWM period.
    """
    fs = p[P_FS]
    dt = 1.0 / fs
    nsub = int(p[P_SUBSTEPS])
    h = dt / nsub
    ibias = p[P_IBIAS]
    irmax = p[P_IREF_MAX]
    bw = p[P_XS_BW]
    axs = -math.expm1(-bw * h)
    record_fine = fine.shape[1] > 0
    track = rip.shape[1] > 0
    isamp = np.empty(4)
    n_turns = p[P_N]
    ge = p[P_GE]
    inv_den = 1.0 / (n_turns * n_turns + ge * p[P_R])
    n_den = n_turns * inv_den
    r_den = p[P_R] * inv_den
    den_i = ge * p[P_R] + n_turns * n_turns
    vs = p[P_V]
    vbar = np.zeros(4)
    fm = np.zeros(4)
    dfm = np.zeros(4)
    m1 = np.zeros(4)
    m2 = np.zeros(4)
    for k in range(k0, k1):
        t = k * dt
        # ---------------- magnets: exact MMF once per sample ----------------
        for j in range(4):
            gs = gap_sum(_disp(st[S_X], st[S_Y], j), p)
            f, df = mmf_update(st[S_PHI + j], gs, z, j, p)
            fm[j] = f
            dfm[j] = df
        # ---------------- sensing ----------------
        for j in range(4):
            isamp[j] = _coil_i(st[S_BLK + j], st[S_VOLT + j], fm[j], ge, vs, n_turns, den_i) + n_i[j, k]
        x_sens = p[P_GAIN_X] * st[S_XS] + n_x[k]
        _dcm_update(st, p, ring_i, ring_d, ring_s, isamp[0], t, tb)
        if p[P_SS_IDEAL] > 0.5:
            y_ss = p[P_GAIN_Y] * st[S_Y] + n_ym[k]   # ideal y sensor instead of DCM (diagnostics)
        else:
            y_ss = p[P_GAIN_Y] * st[S_SSLP]
        dn = int(st[S_DN])
        ring_x[dn % RING] = x_sens
        ring_y[dn % RING] = y_ss
        dn += 1
        st[S_DN] = dn
        x_ctl = _delayed(ring_x, dn, p[P_DELAY_X] * fs)
        y_ctl = _delayed(ring_y, dn, p[P_DELAY_Y] * fs)
        # ---------------- control ----------------
        if p[P_PID_ON] > 0.5:
            ux = _pid(st, p, S_PIDX_I, r_x[k] - x_ctl)
            uy = _pid(st, p, S_PIDY_I, r_y[k] - y_ctl)
        else:
            ux = 0.0
            uy = 0.0
        st[S_UX] = ux
        st[S_UY] = uy
        cx = ux + inj_x[k]
        cy = uy + inj_y[k]
        refs = (ibias + cy, ibias - cy, ibias + cx, ibias - cx)
        for j in range(4):
            rj = refs[j]
            if rj < 0.0:
                rj = 0.0
            elif rj > irmax:
                rj = irmax
            st[S_IREF + j] = rj
        # ---------------- record ----------------
        out[O_T, k] = t
        out[O_XM, k] = x_ctl
        out[O_YM, k] = st[S_Y] + n_ym[k]
        out[O_YSS, k] = y_ctl
        for j in range(4):
            out[O_I + j, k] = isamp[j]
            out[O_B + j, k] = st[S_PHI + j] / p[P_AP]
            out[O_D + j, k] = st[S_DUTY + j]
        out[O_UX, k] = ux
        out[O_UY, k] = uy
        out[O_XT, k] = st[S_X]
        out[O_YT, k] = st[S_Y]
        rr = math.sqrt(st[S_X] ** 2 + st[S_Y] ** 2)
        out[O_CONTACT, k] = 1.0 if rr >= p[P_CLEAR] else 0.0
        if rr >= p[P_CLEAR] and st[S_TCONTACT] < 0.0:
            st[S_TCONTACT] = t
        out[O_FMX, k] = st[S_FMX]
        out[O_FMY, k] = st[S_FMY]
        out[O_YSSRAW, k] = st[S_YSSRAW]
        out[O_VX, k] = st[S_VX]
        out[O_VY, k] = st[S_VY]
        # ---------------- integrate to t_{k+1} ----------------
        fxe = f_x[k]
        fye = f_y[k]
        for s in range(nsub):
            t_a = (k + s / nsub) * dt
            t_b = (k + (s + 1.0) / nsub) * dt
            for j in range(4):
                rip_n, m1[j], m2[j], sv = _advance_magnet(st, p, j, t_a, t_b, fm, dfm, rip, rip_n,
                                                          track, n_den, r_den, ge, inv_den)
                vbar[j] = sv / h
            fmx, fmy = _mean_forces(p, m1, m2, h)
            _rotor_step(st, p, h, fmx, fmy, fxe, fye)
            # x probe: first-order low-pass of the true position
            st[S_XS] += axs * (st[S_X] - st[S_XS])
            if record_fine:
                col = k * nsub + s
                fine[0, col] = t_b
                for j in range(4):
                    fine[1 + j, col] = _coil_i(st[S_BLK + j], st[S_VOLT + j], fm[j], ge, vs, n_turns, den_i)
                    fine[5 + j, col] = st[S_PHI + j]
                    fine[9 + j, col] = vbar[j]
    return rip_n
