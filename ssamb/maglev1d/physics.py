r"""The levitated ball's model and its compiled replay.

Geometry and signs
------------------
:math:`y` is the ball's position below the magnet's face (m), growing downwards; the face is
the upper stop :math:`y_{top}` (the ball sticks there when pulled against it), a lower stop at
:math:`y_{bot}` carries the ball when the magnet does not. Gravity pulls towards :math:`+y`, the
magnet towards :math:`-y`.

Equations (nominal model)
-------------------------
Inductance and force (the source repository's family; co-energy :math:`\tfrac12 L(y) i^2`):

.. math::

    L(y) = k_0 + \frac{k}{1 + y/a}, \qquad
    F(y, i) = \tfrac12 i^2 \left|\frac{dL}{dy}\right| = \frac{k\, i^2}{2a\,(1 + y/a)^2}

Motion, with an extra force :math:`f` (zero nominally, an effect or the noise otherwise):

.. math:: m\ddot y = m g + f - F(y, i_m)

Coil (terminal current :math:`i`, flux linkage :math:`\lambda = L(y)\, i_m`, total series
resistance :math:`R` = coil + current-sense shunt, voltage :math:`v` from the PWM stage):

.. math:: \frac{d\lambda}{dt} = v - R\,i, \qquad
          i = i_m + \frac{\tau_e}{L}\frac{d\lambda}{dt}

so that :math:`L\,\dot i_m = L\frac{v - R i_m}{L + R\tau_e} - (i_m + i_r) \frac{dL}{dy}\dot y`: the
motion term (back-EMF of the moving ball) is included, with the core's remanent magnetisation
:math:`i_r` (an equivalent current, zero nominally: the ``remanence`` effect) in the flux and the
force, :math:`F = \tfrac12 (i_m + i_r)^2 |dL/dy|`; :math:`\tau_e = 0`
nominally (the eddy-current effect sets it: a core-loss branch in parallel with :math:`L`, the
force-producing current :math:`i_m` lagging the terminal current). The current cannot reverse
(the stage's freewheeling diode): :math:`i_m \ge 0`.

PWM stage: the command :math:`u` (V) becomes a duty :math:`D = \lfloor u N_{pwm}/V_{ref}\rfloor /
N_{pwm}` (the 8-bit duty the acquisition program's ``esc_pwm = 254/Vref`` implies), applied as
the average voltage :math:`v = D\,V_{max} - V_d` (``amplifier.v_max_v``; the switch's and the
freewheeling diode's drop ``amplifier.drop_v``, zero in the published model) from the sample
instant (plus a computation delay, an effect) until the next.

Stops: a ball reaching a stop loses its velocity (restitution :math:`e`; it rests when the
rebound is below 10 mm/s) and stays in contact while the net force presses it there: on the
magnet while :math:`F > m g + f`, on the lower stop while :math:`F < m g + f`. It lifts off when
the force changes sign -- sticking and lift-off follow from the force law, no extra rule.

Sensors: the position ADC count is :math:`\operatorname{round}(y_s / q_y)` clipped to
:math:`[0, N_y]` (:math:`q_y` = 0.05/1023 m), of the sensor's reading
:math:`y_s = \ell + q (\ell - c)^2 + n_y`, :math:`\ell = g_s y + o_s` (scale and zero
``sensors.position_gain``/``position_offset_m``; an optical sensor's curvature :math:`q`
``sensors.position_curvature_per_m`` about the reading :math:`c` = ``sensors.position_centre_m``,
zero in the published linear sensor, leaves the scale and the reading at :math:`c` as they are); the
current ADC count likewise of :math:`i + n_i` (:math:`q_i = 5/(2.2\cdot 1023)` A). The noise terms
are white, Gaussian, one draw per sample, their levels in the config (``noise``): a replay is a
realisation of this noise. A random force (``noise.force_n``, held over a sample) stands for the
air and the table.

Quantisers: the rig rounds (the ADCs to the nearest count, the PWM's duty down to a whole step).
A replay with ``replay.additive_quantisers`` 1 replaces each rounding error by a uniform draw
:math:`d_k \in [-1/2, 1/2)` of one step (the ADC: :math:`\mathrm{count} = x/q + d_k`; the PWM:
:math:`D = (u N_{pwm}/V_{ref} - 1/2 + d_k)/N_{pwm}`, the truncation's mean half step kept), clipped
to the same ranges. With the sensor noise ahead of the ADCs (0.35 position counts, 1.4 current
counts) the rounding error is close to such a draw, so the two replays have the same noise; but a
rounded replay is a discontinuous function of the parameters -- a change far below any finite
difference flips a count, the loop feeds the flip back, and for a fixed seed the replay becomes
another realisation -- while an additive one, for a fixed seed, is smooth in every parameter
(contact events and the controller's integrator resets aside). Rigs simulated as data
(:meth:`ssamb.maglev1d.device.Maglev1D.simulate_log`) round.

Numerics: RK4 with ``replay.substeps`` fixed steps per sample, the interval split at the
computation delay so that the output is smooth in every parameter; contact events are resolved
at the step they occur in.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from .controller import step as controller_step

__all__ = ["KNOBS", "knob_index", "neutral_knobs", "inductance_h", "force_n", "equilibrium_current_a",
           "equilibrium", "simulate", "knobs_of", "reading_m", "position_m", "reading_slope"]

#: the kernel's parameter vector: physical parameters, noise levels, effect knobs (neutral values
#: in :func:`neutral_knobs`); effects set theirs through :mod:`ssamb.maglev1d.effects`
KNOBS = (
    # physics
    "mass_kg", "gravity_m_per_s2", "k0_h", "k_h", "a_m", "r_ohm", "v_max_v", "v_ref_v", "pwm_steps",
    "position_lsb_m", "position_counts", "current_lsb_a", "current_counts", "top_m", "bottom_m",
    "restitution", "substeps",
    # noise
    "noise_position_m", "noise_current_a", "noise_force_n",
    # effects
    "sensor_delay_s", "actuation_delay_s", "sensor_gain", "sensor_offset_m", "extra_force_n", "eddy_tau_s",
    "saturation_per_a2", "drop_v", "r_rate_ohm_per_s", "current_offset_a", "remanence_a",
    "sensor_curvature_per_m", "sensor_centre_m",
    # numerics
    "additive_quantisers",
)
_I = {n: j for j, n in enumerate(KNOBS)}
(M, G, K0, K, A, R, VMAX, VREF, NPWM, QY, NY, QI, NI, YTOP, YBOT, REST, NSUB, SY, SI, SF, DY, DU, GY, OY,
 FEXT, TAUE, CSAT, VDROP, RRATE, IOFF, IREM, QS, RC, QADD) = range(len(KNOBS))


def knob_index(name: str) -> int:
    return _I[name]


def neutral_knobs() -> dict:
    """Effect knobs at 'no effect'."""
    return {"sensor_delay_s": 0.0, "actuation_delay_s": 0.0, "sensor_gain": 1.0, "sensor_offset_m": 0.0,
            "extra_force_n": 0.0, "eddy_tau_s": 0.0, "saturation_per_a2": 0.0, "drop_v": 0.0,
            "r_rate_ohm_per_s": 0.0, "current_offset_a": 0.0, "remanence_a": 0.0, "sensor_curvature_per_m": 0.0,
            "sensor_centre_m": 0.005}


# -- the force law ----------------------------------------------------------------------------
def inductance_h(y, k0_h, k_h, a_m):
    r""":math:`L(y) = k_0 + k/(1 + y/a)` (H)."""
    return k0_h + k_h / (1.0 + np.asarray(y, float) / a_m)


def force_n(y, i, k_h, a_m):
    r""":math:`F = k i^2 / (2 a (1 + y/a)^2)` (N), towards the magnet."""
    y = np.asarray(y, float)
    return k_h * np.asarray(i, float) ** 2 / (2.0 * a_m * (1.0 + y / a_m) ** 2)


def equilibrium_current_a(y, mass_kg, g, k_h, a_m, extra_force_n=0.0):
    r"""The current that holds the ball at ``y``: :math:`i = (1 + y/a)\sqrt{2 a (m g + f)/k}`."""
    return (1.0 + np.asarray(y, float) / a_m) * np.sqrt(2.0 * a_m * (mass_kg * g + extra_force_n) / k_h)


@numba.njit(cache=True)
def _reading(p, y):
    """The position sensor's noise-free reading of the true position ``y`` (module docstring)."""
    lin = p[GY] * y + p[OY]
    z = lin - p[RC]
    return lin + p[QS] * z * z


def reading_m(p: np.ndarray, y):
    r"""The position sensor's reading :math:`y_s = \ell + q (\ell - c)^2`, :math:`\ell = g_s y + o_s`,
    of the true position ``y`` (m), noise and ADC aside."""
    lin = p[GY] * np.asarray(y, float) + p[OY]
    return lin + p[QS] * (lin - p[RC]) ** 2


def position_m(p: np.ndarray, reading):
    r"""The true position whose noise-free reading is ``reading`` (the inverse of :func:`reading_m` on
    its monotonic branch: :math:`\ell - c = 2 (y_s - c)/(1 + \sqrt{1 + 4 q (y_s - c)})`)."""
    d = np.asarray(reading, float) - p[RC]
    disc = np.maximum(1.0 + 4.0 * p[QS] * d, 1e-12)
    lin = p[RC] + 2.0 * d / (1.0 + np.sqrt(disc))
    return (lin - p[OY]) / p[GY]


def reading_slope(p: np.ndarray, y):
    r""":math:`dy_s/dy = g_s (1 + 2 q (\ell - c))`: the sensor's local scale at the true position ``y``."""
    lin = p[GY] * np.asarray(y, float) + p[OY]
    return p[GY] * (1.0 + 2.0 * p[QS] * (lin - p[RC]))


def equilibrium(p: np.ndarray, reading_m: float) -> tuple[float, float, float]:
    r"""The ball at rest where the sensor reads ``reading_m``: true position (the sensor model's
    inverse), the terminal current that holds it (force law with saturation and the extra force:
    :math:`i^2/(1 + c i^2) = i_{law}^2`), and the command that drives it
    (:math:`u = V_{ref} (R i + V_d)/V_{max}`, the PWM's truncation aside)."""
    y = float(position_m(p, reading_m))
    i_law = float(equilibrium_current_a(y, p[M], p[G], p[K], p[A], p[FEXT]))
    den = 1.0 - p[CSAT] * i_law ** 2
    i = (i_law / math.sqrt(den) if den > 0 else i_law) - p[IREM]
    u = p[VREF] * (p[R] * i + p[VDROP]) / p[VMAX]
    return float(y), float(i), float(u)


# -- the kernel -------------------------------------------------------------------------------
@numba.njit(cache=True)
def _deriv(p, y, vel, im, v, r, f, mode):
    a = p[A]
    s = 1.0 + y / a
    ind = p[K0] + p[K] / s
    dind = -p[K] / (a * s * s)
    i_f = im + p[IREM]
    force = 0.5 * i_f * i_f * (-dind) / (1.0 + p[CSAT] * i_f * i_f)
    if mode == 0:
        dy = vel
        dv = p[G] + (f - force) / p[M]
    else:
        dy = 0.0
        dv = 0.0
    tau = p[TAUE]
    dim = (v - r * im) / (ind + r * tau) - i_f * dind * dy / ind
    return dy, dv, dim


@numba.njit(cache=True)
def _net_accel(p, y, im, f):
    a = p[A]
    s = 1.0 + y / a
    i_f = im + p[IREM]
    force = 0.5 * i_f * i_f * p[K] / (a * s * s) / (1.0 + p[CSAT] * i_f * i_f)
    return p[G] + (f - force) / p[M]


@numba.njit(cache=True)
def _terminal(p, y, im, v, r):
    tau = p[TAUE]
    if tau == 0.0:
        return im
    ind = p[K0] + p[K] / (1.0 + y / p[A])
    return im + tau * (v - r * im) / (ind + r * tau)


@numba.njit(cache=True)
def _rk4(p, st, v, r, f, h):
    """One RK4 step of (y, vel, im) in the current contact mode ``st[3]``; contact resolved after."""
    y, vel, im, mode = st[0], st[1], st[2], int(st[3])
    k1 = _deriv(p, y, vel, im, v, r, f, mode)
    k2 = _deriv(p, y + 0.5 * h * k1[0], vel + 0.5 * h * k1[1], im + 0.5 * h * k1[2], v, r, f, mode)
    k3 = _deriv(p, y + 0.5 * h * k2[0], vel + 0.5 * h * k2[1], im + 0.5 * h * k2[2], v, r, f, mode)
    k4 = _deriv(p, y + h * k3[0], vel + h * k3[1], im + h * k3[2], v, r, f, mode)
    y += h / 6.0 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
    vel += h / 6.0 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
    im += h / 6.0 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2])
    if im < 0.0:
        im = 0.0                        # the freewheeling diode blocks a reverse current
    touched = 0
    if mode == 0:
        stop = 1 if y <= p[YTOP] else (2 if y >= p[YBOT] else 0)
        if stop:
            y = p[YTOP] if stop == 1 else p[YBOT]
            vel = -p[REST] * vel        # the rebound; it rests when the rebound is below 10 mm/s
            touched = 1
            if abs(vel) < 0.01:
                vel = 0.0
                mode = stop
    else:
        touched = 1
        acc = _net_accel(p, y, im, f)
        if (mode == 1 and acc > 0.0) or (mode == 2 and acc < 0.0):
            mode = 0                    # the net force pulls it off the stop
    st[0], st[1], st[2], st[3] = y, vel, im, mode
    return touched


@numba.njit(cache=True)
def _amplifier(p, u, d):
    """Average coil voltage of the PWM stage for the command ``u`` (``d``: the truncation's
    uniform draw in :math:`[-1/2, 1/2)` when the quantisers are additive)."""
    duty = u / p[VREF]
    if p[NPWM] > 0.0:
        if p[QADD] > 0.0:
            duty = (duty * p[NPWM] - 0.5 + d) / p[NPWM]
        else:
            duty = math.floor(duty * p[NPWM] + 1e-9) / p[NPWM]
    if duty < 0.0:
        duty = 0.0
    elif duty > 1.0:
        duty = 1.0
    return duty * p[VMAX] - p[VDROP]


@numba.njit(cache=True)
def _adc(x, lsb, counts, add, d):
    if add > 0.0:
        c = x / lsb + d                 # additive: the rounding error as a uniform draw
    else:
        c = math.floor(x / lsb + 0.5)
    if c < 0.0:
        c = 0.0
    elif c > counts:
        c = counts
    return c * lsb


@numba.njit(cache=True)
def _hermite(t0, y0, v0, t1, y1, v1, t):
    h = t1 - t0
    if h <= 0.0:
        return y0
    s = (t - t0) / h
    h00 = (1.0 + 2.0 * s) * (1.0 - s) ** 2
    h10 = s * (1.0 - s) ** 2
    h01 = s * s * (3.0 - 2.0 * s)
    h11 = s * s * (s - 1.0)
    return h00 * y0 + h10 * h * v0 + h01 * y1 + h11 * h * v1


@numba.njit(cache=True)
def _simulate(p, g, yd, t0_s, seg_a, seg_b, init, ny, ni, nf, qy, qi, qu, out_y, out_i, out_u, out_true, out_contact):
    ts = g[0]
    nsub = int(p[NSUB])
    st = np.zeros(4)
    ctl = np.zeros(4)
    hist_t = np.zeros(2 * nsub + 4)
    hist_y = np.zeros(2 * nsub + 4)
    hist_v = np.zeros(2 * nsub + 4)
    for s in range(len(seg_a)):
        a, b = seg_a[s], seg_b[s]
        st[0], st[1], st[2] = init[s, 0], init[s, 1], init[s, 2]
        st[3] = 0.0
        if st[0] <= p[YTOP]:
            st[0] = p[YTOP]
            st[1] = 0.0
            st[3] = 1.0
        elif st[0] >= p[YBOT]:
            st[0] = p[YBOT]
            st[1] = 0.0
            st[3] = 2.0
        ctl[0], ctl[1], ctl[2], ctl[3] = init[s, 3], init[s, 4], init[s, 5], 0.0
        v_prev = _amplifier(p, init[s, 6], 0.0)
        # history of the last interval: one node at the start (the ball's state, moving at v0)
        nh = 2
        hist_t[0], hist_y[0], hist_v[0] = -ts, st[0] - ts * st[1], st[1]
        hist_t[1], hist_y[1], hist_v[1] = 0.0, st[0], st[1]
        for k in range(a, b):
            t = t0_s + k * ts
            r = p[R] + p[RRATE] * t
            # -- sample: position (delayed reading of the past trajectory) and current
            tq = -p[DY]
            yq = st[0]
            if p[DY] > 0.0:
                j = nh - 1
                while j > 0 and hist_t[j - 1] > tq:
                    j -= 1
                if j == 0:
                    yq = hist_y[0]
                else:
                    yq = _hermite(hist_t[j - 1], hist_y[j - 1], hist_v[j - 1], hist_t[j], hist_y[j], hist_v[j], tq)
            reading = _reading(p, yq) + p[SY] * ny[k]
            ym = _adc(reading, p[QY], p[NY], p[QADD], qy[k])
            it = _terminal(p, st[0], st[2], v_prev, r)
            im_meas = _adc(it + p[IOFF] + p[SI] * ni[k], p[QI], p[NI], p[QADD], qi[k])
            u = controller_step(ctl, ym, im_meas, yd[k], g)
            out_y[k] = ym
            out_i[k] = im_meas
            out_u[k] = u
            out_true[k, 0] = st[0]
            out_true[k, 1] = it
            out_true[k, 2] = st[2]
            v_new = _amplifier(p, u, qu[k])
            f = p[FEXT] + p[SF] * nf[k]
            # -- integrate to the next sample: the old voltage until the computation delay ends
            n1 = 0
            if p[DU] > 0.0:
                n1 = int(round(nsub * p[DU] / ts))
                if n1 < 1:
                    n1 = 1
                if n1 > nsub - 1:
                    n1 = nsub - 1
            hist_t[0], hist_y[0], hist_v[0] = 0.0, st[0], st[1]
            nh = 1
            touched = 0
            tl = 0.0
            for part in range(2):
                if part == 0:
                    nstep, dur, v = n1, p[DU], v_prev
                else:
                    nstep, dur, v = nsub - n1, ts - p[DU] if n1 > 0 else ts, v_new
                if nstep == 0:
                    continue
                hh = dur / nstep
                for _ in range(nstep):
                    if v < 0.0 and st[2] <= 0.0:
                        v = 0.0             # no current, no freewheeling: no negative voltage
                    touched |= _rk4(p, st, v, r, f, hh)
                    tl += hh
                    hist_t[nh], hist_y[nh], hist_v[nh] = tl, st[0], st[1]
                    nh += 1
            # shift the history so that the next sample instant is t = 0
            for j in range(nh):
                hist_t[j] -= ts
            out_contact[k] = touched
            v_prev = v_new
    return 0


def simulate(knobs: np.ndarray, gains: np.ndarray, yd: np.ndarray, segments, init: np.ndarray,
             noise: np.ndarray | None, t0_s: float = 0.0, dither: np.ndarray | None = None) -> dict:
    """Run the model over ``segments`` of a record.

    Parameters
    ----------
    knobs : numpy.ndarray
        The parameter vector (:data:`KNOBS` order).
    gains : numpy.ndarray
        The controller's settings (:func:`ssamb.maglev1d.controller.gains_of`).
    yd : numpy.ndarray
        The position reference of every sample (m).
    segments : sequence of (int, int)
        Sample ranges ``[a, b)`` to simulate, each from its own initial state.
    init : numpy.ndarray
        ``(n_segments, 7)``: ``y0`` (m), ``v0`` (m/s), ``i0`` (A), the controller's state before
        sample ``a`` (``e_prev, I, J``) and the command ``u`` of sample ``a-1`` (V).
    noise : numpy.ndarray or None
        ``(3, n)`` standard normal draws (position, current, force), or None for none.

    Returns
    -------
    dict
        ``y``, ``i``, ``u`` (the logged channels; NaN outside the segments), ``state``
        (``(n, 3)``: true position, terminal current, force-producing current) and ``contact``
        (1 where the ball touched a stop in the interval after a sample).
    """
    n = len(yd)
    seg = np.asarray(segments, dtype=np.int64).reshape(-1, 2)
    if noise is None:
        noise = np.zeros((3, n))
    if dither is None:
        dither = np.zeros((3, n))
    out = {c: np.full(n, np.nan) for c in ("y", "i", "u")}
    true = np.full((n, 3), np.nan)
    contact = np.zeros(n, dtype=np.int64)
    _simulate(np.asarray(knobs, float), np.asarray(gains, float), np.asarray(yd, float), float(t0_s),
              np.ascontiguousarray(seg[:, 0]), np.ascontiguousarray(seg[:, 1]), np.asarray(init, float).reshape(-1, 7),
              noise[0], noise[1], noise[2], dither[0], dither[1], dither[2],
              out["y"], out["i"], out["u"], true, contact)
    out["state"] = true
    out["contact"] = contact
    return out


def knobs_of(cfg, knobs: dict | None = None) -> np.ndarray:
    """The kernel's parameter vector of a device config, with effect knobs ``knobs`` set."""
    c = cfg
    v = {
        "mass_kg": c["ball"]["mass_kg"], "gravity_m_per_s2": c["ball"]["gravity_m_per_s2"],
        "k0_h": c["magnet"]["k0_h"], "k_h": c["magnet"]["k_h"], "a_m": c["magnet"]["a_m"],
        "r_ohm": c["coil"]["r_ohm"] + c["coil"]["r_shunt_ohm"],
        "v_max_v": c["amplifier"]["v_max_v"], "v_ref_v": c["controller"]["v_ref_v"],
        "pwm_steps": c["amplifier"]["pwm_steps"],
        "position_lsb_m": c["sensors"]["position_full_scale_m"] / c["sensors"]["position_counts"],
        "position_counts": c["sensors"]["position_counts"],
        "current_lsb_a": (c["sensors"]["current_full_scale_v"]
                          / (c["coil"]["r_shunt_ohm"] * c["sensors"]["current_counts"])),
        "current_counts": c["sensors"]["current_counts"],
        "top_m": c["stops"]["top_m"], "bottom_m": c["stops"]["bottom_m"], "restitution": c["stops"]["restitution"],
        "substeps": c["replay"]["substeps"],
        "noise_position_m": c["noise"]["position_m"], "noise_current_a": c["noise"]["current_a"],
        "noise_force_n": c["noise"]["force_n"],
        "additive_quantisers": float(c["replay"].get("additive_quantisers", 0)),
    }
    v.update(neutral_knobs())
    v.update(knobs or {})
    v["sensor_gain"] *= c["sensors"]["position_gain"]          # the sensor's nominal scale and zero,
    v["sensor_offset_m"] += c["sensors"]["position_offset_m"]  # then an effect's on top
    v["sensor_curvature_per_m"] += c["sensors"]["position_curvature_per_m"]
    v["sensor_centre_m"] = c["sensors"]["position_centre_m"]
    v["drop_v"] += c["amplifier"]["drop_v"]
    return np.array([float(v[n]) for n in KNOBS])
