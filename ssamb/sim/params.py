r"""Physical parameters of the simulated AMB, derived from the configuration.

:func:`amb_params` turns ``config.yaml`` (Table 1 plus the modelling assumptions) into an
:class:`AMBParams` dataclass of SI quantities, and :meth:`AMBParams.pack` into the flat float
array that the compiled kernel reads (index constants ``P_*`` below).

Geometry (paper Fig. 2, Table 1; 8-pole heteropolar stator, 4 electromagnets of 2 poles)
------------------------------------------------------------------------------------------
* pole face area :math:`A_p = r_w \, l_a` (pole width times axial length);
* each electromagnet's poles sit at :math:`\pm\alpha` (22.5 deg) from its axis, so the two
  airgaps in series sum to :math:`g_1 + g_2 = 2 (g_0 - \xi \cos\alpha)` where :math:`\xi` is
  the rotor displacement towards that magnet (exact to first order; the transverse
  displacement cancels);
* iron path of one magnet: two pole legs of length :math:`r_c - r_p` at area :math:`A_p`, a
  back-iron arc of length :math:`(\pi/4)(r_c + r_s)/2` at area :math:`(r_s - r_c) l_a`, a
  journal arc of length :math:`(\pi/4)(r_r + r_j)/2` plus two radial journal legs of
  :math:`(r_j - r_r)/2` at area :math:`(r_j - r_r) l_a`;
* turns per electromagnet :math:`N = n_{coils} \times 50`.

Reluctance of the magnet at the centred position (saturation off):
:math:`\mathcal{R} = (2 g_0 + l_{eq}/\mu_r)/(\mu_0 A_p)` with the equivalent iron length
:math:`l_{eq} = \sum_s l_s A_p / A_s`; inductance :math:`L = N^2/\mathcal{R}`.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Mapping

import numpy as np

MU0 = 4e-7 * math.pi  # H/m (the SI value to 1e-9 relative; the paper's mu_0)

__all__ = ["MU0", "AMBParams", "amb_params"]

# --- indices into the packed parameter array read by the kernel -------------------------
_names = [
    "N", "R", "GE", "V", "TPWM", "KP_PA", "KI_PA", "DMIN", "DMAX", "IREF_MAX", "IBIAS",
    "AP", "G0", "COSA", "MASS", "GRAV", "CLEAR", "KC", "CC",
    "SAT", "BKNEE", "PEXP", "HYST", "HC", "NPLAY", "RMAX", "MUR",
    "L_POLE", "L_BACK", "A_BACK", "L_ROT", "A_ROT", "LEQ",
    "FS", "SUBSTEPS", "UMAX",
    "PID_KP", "PID_KI_HALF", "PID_AD", "PID_BD",
    "SS_W", "SS_ALPHA", "SS_ORDER", "SS_POLY", "SS_GATE", "SS_GAIN", "SS_OFF", "SS_MIN_DD",
    "XS_BW",
    "DELAY_X", "DELAY_Y", "GAIN_X", "GAIN_Y", "DEADTIME", "XCOUP",
    "PID_ON", "CLAMP", "CLAMP_X", "CLAMP_Y", "SS_IDEAL",
    # derived constants (reciprocals precomputed for the kernel)
    "INV_MU0MUR", "INV_BKNEE", "INV_AP", "INV_ABACK", "INV_AROT", "GAPK", "LFE",
]
_names += [f"PLAY_R{k}" for k in range(16)] + [f"PLAY_INVR{k}" for k in range(16)]
# appended (existing indices stay put): iron MMF constants and the elastic hysteresis slope
_names += ["FE_C1", "FE_C2", "INV_PHIK", "HYST_DF"]
for _i, _n in enumerate(_names):
    globals()["P_" + _n] = _i
P_SIZE = len(_names)
__all__ += ["P_" + n for n in _names] + ["P_SIZE"]


@dataclass(frozen=True)
class AMBParams:
    """SI parameters of the nonlinear AMB model (see module docstring for the derivations)."""

    turns: int                   # N, turns per electromagnet
    r_coil_ohm: float
    eddy_conductance_s: float    # g_e = 1/r_e of the equivalent shorted one-turn winding (0: off)
    v_supply_v: float
    f_pwm_hz: float
    pa_kp_per_a: float
    pa_ki_per_a: float
    duty_min: float
    duty_max: float
    i_ref_max_a: float
    i_bias_a: float
    pole_area_m2: float
    airgap_m: float
    pole_half_angle_rad: float
    mass_kg: float
    gravity_m_per_s2: float
    clearance_m: float
    contact_stiffness_n_per_m: float
    contact_damping_n_s_per_m: float
    saturation: bool
    b_knee_t: float
    saturation_exponent: float
    hysteresis: bool
    coercive_field_a_per_m: float
    n_play: int
    play_width_max_t: float
    mu_r: float
    l_pole_m: float              # both pole legs, at the pole area
    l_back_m: float
    a_back_m2: float
    l_rotor_m: float
    a_rotor_m2: float
    fs_hz: float
    substeps: int
    u_max_a: float
    derivative_filter_hz: float
    pid_kp: float
    pid_ki: float
    pid_kd: float
    ss_window: int
    ss_lowpass_hz: float
    ss_lowpass_order: int
    ss_trend_order: int
    ss_gate: float
    x_bandwidth_hz: float

    # ---- derived quantities -------------------------------------------------------------
    @property
    def l_eq_m(self) -> float:
        r"""Iron path expressed as an equivalent length at the pole area, :math:`\sum l_s A_p/A_s`."""
        ap = self.pole_area_m2
        return self.l_pole_m + self.l_back_m * ap / self.a_back_m2 + self.l_rotor_m * ap / self.a_rotor_m2

    @property
    def l_iron_total_m(self) -> float:
        return self.l_pole_m + self.l_back_m + self.l_rotor_m

    @property
    def cos_alpha(self) -> float:
        return math.cos(self.pole_half_angle_rad)

    def inductance_h(self, displacement_m: float = 0.0) -> float:
        r"""Small-signal coil inductance of one magnet, saturation and hysteresis off.

        :math:`L = \mu_0 N^2 A_p / (2 (g_0 - \xi\cos\alpha) + l_{eq}/\mu_r)` (paper eq. (1)).
        """
        gsum = 2 * (self.airgap_m - displacement_m * self.cos_alpha)
        return MU0 * self.turns**2 * self.pole_area_m2 / (gsum + self.l_eq_m / self.mu_r)

    def force_n(self, current_a: float, displacement_m: float = 0.0) -> float:
        r"""Static force of one electromagnet, linear iron:
        :math:`F = \mu_0 N^2 A_p i^2 \cos\alpha / (2 g_1 + l_{eq}/\mu_r)^2`.

        With :math:`l_{eq}/\mu_r \to 0` this is the textbook law
        :math:`F = \mu_0 N^2 A_p i^2\cos\alpha/(4 g^2)`.
        """
        gsum = 2 * (self.airgap_m - displacement_m * self.cos_alpha) + self.l_eq_m / self.mu_r
        return MU0 * self.turns**2 * self.pole_area_m2 * current_a**2 * self.cos_alpha / gsum**2

    def ki_ks(self, i_ctrl_a: float = 0.0) -> tuple[float, float]:
        r"""Current and position stiffness of a differential magnet pair at the centre.

        With :math:`F = k (i_0+i_c)^2/G_+^2 - k (i_0 - i_c)^2/G_-^2`,
        :math:`G_\pm = 2(g_0 \mp \xi\cos\alpha) + l_{eq}/\mu_r`, :math:`k = \mu_0 N^2 A_p\cos\alpha`:
        :math:`k_i = \partial F/\partial i_c = 4 k i_0 / G^2` and
        :math:`k_s = \partial F/\partial \xi = 8 k \cos\alpha (i_0^2 + i_c^2) / G^3` at :math:`\xi = 0`.
        """
        k = MU0 * self.turns**2 * self.pole_area_m2 * self.cos_alpha
        g = 2 * self.airgap_m + self.l_eq_m / self.mu_r
        i0 = self.i_bias_a
        ki = 4 * k * i0 / g**2
        ks = 8 * k * self.cos_alpha * (i0**2 + i_ctrl_a**2) / g**3
        return ki, ks

    def ripple_pp_a(self, duty: float, displacement_m: float = 0.0) -> float:
        """Peak-to-peak PWM ripple of a two-state amplifier, :math:`2 V D (1-D) T / L`."""
        return 2 * self.v_supply_v * duty * (1 - duty) / self.f_pwm_hz / self.inductance_h(displacement_m)

    def pack(self, **overrides) -> np.ndarray:
        """The flat parameter array of the compiled kernel (effects and modes set via overrides)."""
        p = np.zeros(P_SIZE)
        dt = 1.0 / self.fs_hz
        wd = 2 * math.pi * self.derivative_filter_hz
        # Tustin discretisation of  Kd s / (1 + s/wd):  D_k = a_d D_{k-1} + b_d (e_k - e_{k-1})
        c = 2.0 / dt
        a_d = (c / wd - 1.0) / (c / wd + 1.0)
        b_d = self.pid_kd * c / (1.0 + c / wd)
        vals = dict(
            N=self.turns, R=self.r_coil_ohm, GE=self.eddy_conductance_s, V=self.v_supply_v,
            TPWM=1.0 / self.f_pwm_hz, KP_PA=self.pa_kp_per_a, KI_PA=self.pa_ki_per_a,
            DMIN=self.duty_min, DMAX=self.duty_max, IREF_MAX=self.i_ref_max_a, IBIAS=self.i_bias_a,
            AP=self.pole_area_m2, G0=self.airgap_m, COSA=self.cos_alpha, MASS=self.mass_kg,
            GRAV=self.gravity_m_per_s2, CLEAR=self.clearance_m, KC=self.contact_stiffness_n_per_m,
            CC=self.contact_damping_n_s_per_m, SAT=float(self.saturation), BKNEE=self.b_knee_t,
            PEXP=self.saturation_exponent, HYST=float(self.hysteresis), HC=self.coercive_field_a_per_m,
            NPLAY=self.n_play, RMAX=self.play_width_max_t, MUR=self.mu_r,
            L_POLE=self.l_pole_m, L_BACK=self.l_back_m, A_BACK=self.a_back_m2,
            L_ROT=self.l_rotor_m, A_ROT=self.a_rotor_m2, LEQ=self.l_eq_m,
            FS=self.fs_hz, SUBSTEPS=self.substeps, UMAX=self.u_max_a,
            PID_KP=self.pid_kp, PID_KI_HALF=self.pid_ki * dt / 2.0, PID_AD=a_d, PID_BD=b_d,
            SS_W=self.ss_window, SS_ORDER=self.ss_lowpass_order, SS_POLY=self.ss_trend_order, SS_GATE=self.ss_gate, SS_ALPHA=1.0 - math.exp(-2 * math.pi * self.ss_lowpass_hz * dt),
            SS_GAIN=1.0, SS_OFF=0.0, SS_MIN_DD=0.02,
            XS_BW=2 * math.pi * self.x_bandwidth_hz,
            DELAY_X=0.0, DELAY_Y=0.0, GAIN_X=1.0, GAIN_Y=1.0, DEADTIME=0.0, XCOUP=0.0,
            PID_ON=1.0, CLAMP=0.0, CLAMP_X=0.0, CLAMP_Y=0.0, SS_IDEAL=0.0,
        )
        vals.update(
            INV_MU0MUR=1.0 / (MU0 * self.mu_r), INV_BKNEE=1.0 / self.b_knee_t,
            INV_AP=1.0 / self.pole_area_m2, INV_ABACK=1.0 / self.a_back_m2,
            INV_AROT=1.0 / self.a_rotor_m2, GAPK=1.0 / (MU0 * self.pole_area_m2),
            LFE=self.l_iron_total_m,
        )
        # iron MMF Phi (c1 + c2 q), q = (|Phi|/(A_p B_k))^p: sum over the sections s of
        # l_s/(mu0 mu_r A_s) and of the same times (A_p/A_s)^p (see magnetics.mmf_anhysteretic)
        pexp = int(self.saturation_exponent)
        ap = self.pole_area_m2
        sections = ((self.l_pole_m, ap), (self.l_back_m, self.a_back_m2), (self.l_rotor_m, self.a_rotor_m2))
        k_fe = 1.0 / (MU0 * self.mu_r)
        vals.update(
            FE_C1=sum(k_fe * l / a for l, a in sections),
            FE_C2=sum(k_fe * l / a * (ap / a) ** pexp for l, a in sections),
            INV_PHIK=1.0 / (ap * self.b_knee_t),
        )
        for k in range(16):
            r = self.play_width_max_t * (k + 1) / self.n_play
            vals[f"PLAY_R{k}"] = r
            vals[f"PLAY_INVR{k}"] = 1.0 / r
        # slope of the hysteresis MMF with every play operator elastic: sum_k l_fe H_c/(K r_k A_p)
        vals["HYST_DF"] = sum(self.l_iron_total_m * self.coercive_field_a_per_m / self.n_play
                              / vals[f"PLAY_R{k}"] / ap for k in range(self.n_play))
        for k, v in overrides.items():
            if k not in vals:
                raise KeyError(f"unknown kernel parameter '{k}'")
            vals[k] = v
        for k, v in vals.items():
            p[globals()["P_" + k]] = float(v)
        return p

    def as_dict(self) -> dict:
        return asdict(self)


def amb_params(cfg: Mapping) -> AMBParams:
    """Build :class:`AMBParams` from a validated configuration dictionary."""
    t1, geo, mag = cfg["table1"], cfg["geometry"], cfg["magnetics"]
    la = t1["axial_length_m"]
    ap = t1["pole_width_m"] * la
    rr, rj, rp, rc, rs = (t1[k] for k in ("r_journal_inner_m", "r_journal_outer_m", "r_pole_m",
                                          "r_backiron_inner_m", "r_stator_outer_m"))
    pitch = 2 * math.pi / geo["n_poles"]  # angle between the two poles of one magnet (one pole pitch)
    l_pole = 2 * (rc - rp)
    l_back = pitch * (rc + rs) / 2
    a_back = (rs - rc) * la
    l_rot = pitch * (rr + rj) / 2 + 2 * (rj - rr) / 2
    a_rot = (rj - rr) * la
    # Eddy currents: an equivalent shorted one-turn winding around the iron. For laminations of
    # thickness d and conductivity sigma, the eddy MMF per unit length is sigma d^2/12 dB/dt
    # (classical lamination loss model), so along the iron path l_fe at flux Phi = B A:
    #   i_e = -(l_fe sigma d^2 / (12 A)) dPhi/dt = -g_e dPhi/dt.
    l_fe = l_pole + l_back + l_rot
    g_e = 0.0
    if mag["eddy_currents"]:
        d = mag["lamination_thickness_m"]
        g_e = l_fe * mag["iron_conductivity_s_per_m"] * d**2 / (12 * ap)
    return AMBParams(
        turns=int(t1["coil_turns"] * geo["coils_per_magnet"]),
        r_coil_ohm=t1["r_coil_ohm"],
        eddy_conductance_s=g_e,
        v_supply_v=t1["v_supply_v"],
        f_pwm_hz=t1["f_pwm_hz"],
        pa_kp_per_a=t1["pa_kp_per_a"],
        pa_ki_per_a=t1["pa_ki_per_a"],
        duty_min=cfg["amplifier"]["duty_min"],
        duty_max=cfg["amplifier"]["duty_max"],
        i_ref_max_a=cfg["amplifier"]["i_ref_max_a"],
        i_bias_a=t1["i_bias_a"],
        pole_area_m2=ap,
        airgap_m=t1["airgap_m"],
        pole_half_angle_rad=math.radians(geo["pole_half_angle_deg"]),
        mass_kg=t1["mass_kg"],
        gravity_m_per_s2=cfg["gravity_m_per_s2"],
        clearance_m=t1["backup_clearance_m"],
        contact_stiffness_n_per_m=cfg["simulation"]["contact_stiffness_n_per_m"],
        contact_damping_n_s_per_m=cfg["simulation"]["contact_damping_n_s_per_m"],
        saturation=bool(mag["saturation"]),
        b_knee_t=mag["b_knee_t"],
        saturation_exponent=mag["saturation_exponent"],
        hysteresis=bool(mag["hysteresis"]),
        coercive_field_a_per_m=mag["coercive_field_a_per_m"],
        n_play=int(mag["n_play_operators"]),
        play_width_max_t=mag["play_width_max_t"],
        mu_r=t1["mu_r"],
        l_pole_m=l_pole,
        l_back_m=l_back,
        a_back_m2=a_back,
        l_rotor_m=l_rot,
        a_rotor_m2=a_rot,
        fs_hz=cfg["controller"]["fs_hz"],
        substeps=int(cfg["simulation"]["substeps"]),
        u_max_a=cfg["controller"]["u_max_a"],
        derivative_filter_hz=cfg["controller"]["derivative_filter_hz"],
        pid_kp=t1["pid_kp_a_per_m"],
        pid_ki=t1["pid_ki_a_per_m_s"],
        pid_kd=t1["pid_kd_a_s_per_m"],
        ss_window=int(cfg["selfsensing"]["window_samples"]),
        ss_lowpass_hz=cfg["selfsensing"]["lowpass_hz"],
        ss_lowpass_order=int(cfg["selfsensing"]["lowpass_order"]),
        ss_trend_order=int(cfg["selfsensing"]["trend_order"]),
        ss_gate=float(cfg["selfsensing"]["residual_gate"]),
        x_bandwidth_hz=cfg["sensors"]["x_bandwidth_hz"],
    )
