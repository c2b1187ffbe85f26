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

__all__ = ["MU0", "AMBParams", "amb_params", "ESTIMATORS", "EDDY_MODELS"]

#: self-sensing estimators (``selfsensing.estimator``), kernel code = index
ESTIMATORS = ("lsq", "peak")
#: eddy-current models (``magnetics.eddy_model``)
EDDY_MODELS = ("ladder", "shorted_turn")
MAX_LADDER = 6       # kernel limit on ladder sections (ssamb.sim.eddy.MAX_LADDER)

# --- indices into the packed parameter array read by the kernel -------------------------
_names = [
    "N", "R", "GE", "V", "TPWM", "KP_PA", "KI_PA", "DMIN", "DMAX", "IREF_MAX", "IBIAS",
    "AP", "G0", "COSA", "MASS", "GRAV", "CLEAR", "KC", "CC",
    "SAT", "BKNEE", "PEXP", "HYST", "HC", "NPLAY", "RMAX", "MUR",
    "LEQ", "FS", "SUBSTEPS", "UMAX", "INV_N", "INV_MASS", "FORCE_K",
    "PID_KP", "PID_KI_HALF", "PID_AD", "PID_BD",
    "SS_W", "SS_ALPHA", "SS_ORDER", "SS_GATE", "SS_GAIN", "SS_OFF", "SS_EST", "SS_MIN", "SS_R",
    "XS_BW",
    "DELAY_X", "DELAY_Y", "GAIN_X", "GAIN_Y", "DEADTIME", "XCOUP",
    "PID_ON", "CLAMP", "CLAMP_X", "CLAMP_Y", "SS_IDEAL",
    # converters of the DSP: quantisation step and largest code (0 step: ideal), computation delay
    "I_Q", "I_INVQ", "I_CMAX", "X_Q", "X_INVQ", "X_CMAX", "CDELAY",
    # eddy ladder: sections, 1/tau_1, and the MMF coefficients c_k = R_fe a_k (A/Wb)
    "NLAD", "LAD_INVTAU", "LAD_TAU",
    # cross-coupling network (0/1) and the half width of its tables (m)
    "XNET", "QHALF",
    # derived constants (reciprocals precomputed for the kernel)
    "INV_AP", "GAPK", "LFE",
    "FE_C1", "FE_C2", "INV_PHIK", "HYST_DF",
]
_names += [f"LAD_C{k}" for k in range(MAX_LADDER)]
_names += [f"PLAY_R{k}" for k in range(16)] + [f"PLAY_INVR{k}" for k in range(16)]
for _i, _n in enumerate(_names):
    globals()["P_" + _n] = _i
P_SIZE = len(_names)
__all__ += ["P_" + n for n in _names] + ["P_SIZE"]


@dataclass(frozen=True)
class AMBParams:
    """SI parameters of the nonlinear AMB model (see module docstring for the derivations)."""

    turns: float                 # N, turns per electromagnet (effective turns: a calibration may give a non-integer)
    r_coil_ohm: float
    eddy_model: str              # "ladder", "shorted_turn" or "off"
    eddy_conductance_s: float    # g_e of the shorted-turn model (0 unless eddy_model is shorted_turn)
    ladder_weights: tuple        # a_k of the lamination ladder (ssamb.sim.eddy); empty unless ladder
    ladder_taus_s: tuple         # tau_k of the ladder (s)
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
    pole_sequence: str
    cross_coupling: bool
    mass_kg: float
    gravity_m_per_s2: float
    weight_share: float          # share of the rotor weight this bearing carries
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
    l_rotor_arc_m: float         # journal arc over one pole pitch
    l_rotor_radial_m: float      # both radial journal legs
    a_rotor_m2: float
    fs_hz: float
    substeps: int
    u_max_a: float
    pid_coefficients: dict       # the kernel's form of controller.pid_discrete (kp, ki_half, a_d, b_d)
    ss_estimator: str
    ss_window: int
    ss_lowpass_hz: float
    ss_lowpass_order: int
    ss_trend_order: int
    ss_gate: float
    x_bandwidth_hz: float
    current_noise_a: float
    current_adc_bits: int
    current_adc_range_a: float
    position_noise_m: float
    position_adc_bits: int
    position_adc_range_m: float
    computation_delay_samples: int
    additive_quantisers: bool = False  # converters that add their rounding error as noise (converter_noise)

    # ---- derived quantities -------------------------------------------------------------
    @property
    def l_rotor_m(self) -> float:
        """Journal path of one magnet: the arc and both radial legs."""
        return self.l_rotor_arc_m + self.l_rotor_radial_m

    @property
    def current_step_a(self) -> float:
        r"""Step of the current converter, :math:`q_i = 2 I_{fs}/2^{b_i}` (0: ideal); 1.22 mA for
        14 bits over +/-10 A."""
        return 2.0 * self.current_adc_range_a / 2**self.current_adc_bits if self.current_adc_bits > 0 else 0.0

    @property
    def position_step_m(self) -> float:
        r"""Step of the position converter, :math:`q_x = 2 X_{fs}/2^{b_x}` (0: ideal); 0.24 um for
        12 bits over +/-0.5 mm."""
        return 2.0 * self.position_adc_range_m / 2**self.position_adc_bits if self.position_adc_bits > 0 else 0.0

    @property
    def l_eq_m(self) -> float:
        r"""Iron path expressed as an equivalent length at the pole area, :math:`\sum l_s A_p/A_s`."""
        ap = self.pole_area_m2
        return self.l_pole_m + self.l_back_m * ap / self.a_back_m2 + self.l_rotor_m * ap / self.a_rotor_m2

    @property
    def l_iron_total_m(self) -> float:
        return self.l_pole_m + self.l_back_m + self.l_rotor_m

    @property
    def r_iron_a_per_wb(self) -> float:
        r"""Linear reluctance of the whole iron loop, :math:`\mathcal R_{fe} = \sum_s l_s/(\mu_0\mu_r A_s)`."""
        return self.l_eq_m / (MU0 * self.mu_r * self.pole_area_m2)

    @property
    def cos_alpha(self) -> float:
        return math.cos(self.pole_half_angle_rad)

    @property
    def weight_n(self) -> float:
        """Static load of the rotor weight on this bearing, ``weight_share`` m g (N, along -y)."""
        return self.weight_share * self.mass_kg * self.gravity_m_per_s2

    def inductance_h(self, displacement_m: float = 0.0) -> float:
        r"""Small-signal coil inductance of one magnet, saturation, hysteresis and eddy currents off.

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
        vals = {**self._pack_core(), **self._pack_dsp(), **self._pack_iron()}
        for k, v in overrides.items():
            if k not in vals:
                raise KeyError(f"unknown kernel parameter '{k}'")
            vals[k] = v
        p = np.zeros(P_SIZE)
        for k, v in vals.items():
            p[globals()["P_" + k]] = float(v)
        return p

    def _pack_core(self) -> dict:
        """Amplifiers, rotor, contact, geometry and the effect/mode switches."""
        return dict(
            N=self.turns, R=self.r_coil_ohm, GE=self.eddy_conductance_s, V=self.v_supply_v,
            TPWM=1.0 / self.f_pwm_hz, KP_PA=self.pa_kp_per_a, KI_PA=self.pa_ki_per_a,
            DMIN=self.duty_min, DMAX=self.duty_max, IREF_MAX=self.i_ref_max_a, IBIAS=self.i_bias_a,
            AP=self.pole_area_m2, G0=self.airgap_m, COSA=self.cos_alpha, MASS=self.mass_kg,
            GRAV=self.weight_n / self.mass_kg, CLEAR=self.clearance_m, KC=self.contact_stiffness_n_per_m,
            CC=self.contact_damping_n_s_per_m, MUR=self.mu_r, LEQ=self.l_eq_m,
            FS=self.fs_hz, SUBSTEPS=self.substeps, UMAX=self.u_max_a,
            INV_N=1.0 / self.turns, INV_MASS=1.0 / self.mass_kg,
            FORCE_K=self.cos_alpha / (MU0 * self.pole_area_m2),   # force per squared flux, Phi^2 cos(a)/(mu0 A_p)
            XS_BW=2 * math.pi * self.x_bandwidth_hz,
            DELAY_X=0.0, DELAY_Y=0.0, GAIN_X=1.0, GAIN_Y=1.0, DEADTIME=0.0, XCOUP=0.0,
            PID_ON=1.0, CLAMP=0.0, CLAMP_X=0.0, CLAMP_Y=0.0, SS_IDEAL=0.0,
            XNET=float(self.cross_coupling), QHALF=1.25 * self.clearance_m,
        )

    def _pack_dsp(self) -> dict:
        """PID (Tustin, see :mod:`ssamb.sim.controller`), self-sensing and converters."""
        dt = 1.0 / self.fs_hz
        pid = self.pid_coefficients
        vals = dict(
            PID_KP=pid["kp"], PID_KI_HALF=pid["ki_half"], PID_AD=pid["a_d"], PID_BD=pid["b_d"],
            SS_W=self.ss_window, SS_ORDER=self.ss_lowpass_order, SS_GATE=self.ss_gate,
            SS_ALPHA=1.0 - math.exp(-2 * math.pi * self.ss_lowpass_hz * dt),
            SS_GAIN=1.0, SS_OFF=0.0, SS_EST=ESTIMATORS.index(self.ss_estimator), SS_MIN=1e-3,
            SS_R=self.r_coil_ohm,      # the DSP's coil resistance (its calibration)
            CDELAY=float(self.computation_delay_samples),
        )
        for key, bits, rng in (("I", self.current_adc_bits, self.current_adc_range_a),
                               ("X", self.position_adc_bits, self.position_adc_range_m)):
            if self.additive_quantisers:     # the converters pass their input: the noise carries the steps
                bits = 0
            vals[key + "_Q"] = 2.0 * rng / 2**bits if bits > 0 else 0.0   # = current_step_a, position_step_m
            vals[key + "_INVQ"] = 2**bits / (2.0 * rng) if bits > 0 else 0.0
            vals[key + "_CMAX"] = 2 ** (bits - 1) - 1 if bits > 0 else 0.0
        return vals

    def _pack_iron(self) -> dict:
        """Saturation, hysteresis and eddy-current constants (see :mod:`ssamb.sim.magnetics`)."""
        pexp = int(self.saturation_exponent)
        ap = self.pole_area_m2
        sections = ((self.l_pole_m, ap), (self.l_back_m, self.a_back_m2), (self.l_rotor_m, self.a_rotor_m2))
        k_fe = 1.0 / (MU0 * self.mu_r)
        vals = dict(
            SAT=float(self.saturation), BKNEE=self.b_knee_t, PEXP=self.saturation_exponent,
            HYST=float(self.hysteresis), HC=self.coercive_field_a_per_m, NPLAY=self.n_play,
            RMAX=self.play_width_max_t,
            INV_AP=1.0 / ap,
            GAPK=1.0 / (MU0 * ap), LFE=self.l_iron_total_m,
            # iron MMF Phi (c1 + c2 q), q = (|Phi|/(A_p B_k))^p: sums over the sections s of
            # l_s/(mu0 mu_r A_s) and of the same times (A_p/A_s)^p (see magnetics.mmf_anhysteretic)
            FE_C1=sum(k_fe * l / a for l, a in sections),
            FE_C2=sum(k_fe * l / a * (ap / a) ** pexp for l, a in sections),
            INV_PHIK=1.0 / (ap * self.b_knee_t),
            NLAD=len(self.ladder_weights),
            LAD_INVTAU=1.0 / self.ladder_taus_s[0] if self.ladder_taus_s else 0.0,
            LAD_TAU=self.ladder_taus_s[0] if self.ladder_taus_s else 0.0,
        )
        for k in range(MAX_LADDER):
            w = self.ladder_weights[k] if k < len(self.ladder_weights) else 0.0
            vals[f"LAD_C{k}"] = self.r_iron_a_per_wb * w
        for k in range(16):
            r = self.play_width_max_t * (k + 1) / self.n_play
            vals[f"PLAY_R{k}"] = r
            vals[f"PLAY_INVR{k}"] = 1.0 / r
        # slope of the hysteresis MMF with every play operator elastic: sum_k l_fe H_c/(K r_k A_p)
        vals["HYST_DF"] = sum(self.l_iron_total_m * self.coercive_field_a_per_m / self.n_play
                              / vals[f"PLAY_R{k}"] / ap for k in range(self.n_play))
        return vals

    def as_dict(self) -> dict:
        return asdict(self)


def _eddy(cfg: Mapping, l_fe: float, ap: float, mu_r: float) -> dict:
    """Eddy-current model parameters (``magnetics`` section): ladder fit or shorted turn.

    Shorted turn (the classical lamination loss model): for laminations of thickness d and
    conductivity sigma the eddy MMF per unit length is sigma d^2/12 dB/dt, so along the iron
    path l_fe at flux Phi = B A_p: i_e = -(l_fe sigma d^2 / (12 A_p)) dPhi/dt = -g_e dPhi/dt.
    Ladder: the lamination diffusion impedance fitted by :func:`ssamb.sim.eddy.fit_ladder`.
    """
    from .eddy import fit_ladder, lamination_tau

    mag = cfg["magnetics"]
    out = {"eddy_model": "off", "eddy_conductance_s": 0.0, "ladder_weights": (), "ladder_taus_s": ()}
    if not mag["eddy_currents"]:
        return out
    d, sigma = mag["lamination_thickness_m"], mag["iron_conductivity_s_per_m"]
    out["eddy_model"] = mag["eddy_model"]
    if mag["eddy_model"] == "shorted_turn":
        out["eddy_conductance_s"] = l_fe * sigma * d**2 / (12 * ap)
    else:
        w, t = fit_ladder(lamination_tau(mu_r, sigma, d), int(mag["eddy_ladder_order"]),
                          float(mag["eddy_fit_max_hz"]))
        out["ladder_weights"], out["ladder_taus_s"] = w, t
    return out


def _converters(cfg: Mapping) -> dict:
    cv = cfg["converters"]
    out = {k: cv[k] for k in ("current_noise_a", "current_adc_bits", "current_adc_range_a", "position_noise_m",
                              "position_adc_bits", "position_adc_range_m", "computation_delay_samples")}
    out["additive_quantisers"] = bool(cv.get("additive_quantisers", 0))
    return out


def amb_params(cfg: Mapping) -> AMBParams:
    """Build :class:`AMBParams` from a validated configuration dictionary."""
    from .controller import pid_kernel_coefficients

    t1, geo, mag = cfg["table1"], cfg["geometry"], cfg["magnetics"]
    la = t1["axial_length_m"]
    ap = t1["pole_width_m"] * la
    rr, rj, rp, rc, rs = (t1[k] for k in ("r_journal_inner_m", "r_journal_outer_m", "r_pole_m",
                                          "r_backiron_inner_m", "r_stator_outer_m"))
    pitch = 2 * math.pi / geo["n_poles"]  # angle between the two poles of one magnet (one pole pitch)
    l_pole = 2 * (rc - rp)
    ss = cfg["selfsensing"]
    return AMBParams(
        turns=float(t1["coil_turns"] * geo["coils_per_magnet"]),
        r_coil_ohm=t1["r_coil_ohm"],
        **_eddy(cfg, l_pole + pitch * (rc + rs) / 2 + pitch * (rr + rj) / 2 + (rj - rr), ap, t1["mu_r"]),
        v_supply_v=t1["v_supply_v"], f_pwm_hz=t1["f_pwm_hz"],
        pa_kp_per_a=t1["pa_kp_per_a"], pa_ki_per_a=t1["pa_ki_per_a"],
        duty_min=cfg["amplifier"]["duty_min"], duty_max=cfg["amplifier"]["duty_max"],
        i_ref_max_a=cfg["amplifier"]["i_ref_max_a"], i_bias_a=t1["i_bias_a"],
        pole_area_m2=ap, airgap_m=t1["airgap_m"],
        pole_half_angle_rad=math.radians(geo["pole_half_angle_deg"]),
        pole_sequence=geo["pole_sequence"], cross_coupling=bool(mag["cross_coupling"]),
        mass_kg=t1["mass_kg"], gravity_m_per_s2=cfg["gravity_m_per_s2"], weight_share=cfg["weight_share"],
        clearance_m=t1["backup_clearance_m"],
        contact_stiffness_n_per_m=cfg["simulation"]["contact_stiffness_n_per_m"],
        contact_damping_n_s_per_m=cfg["simulation"]["contact_damping_n_s_per_m"],
        saturation=bool(mag["saturation"]), b_knee_t=mag["b_knee_t"],
        saturation_exponent=mag["saturation_exponent"], hysteresis=bool(mag["hysteresis"]),
        coercive_field_a_per_m=mag["coercive_field_a_per_m"], n_play=int(mag["n_play_operators"]),
        play_width_max_t=mag["play_width_max_t"], mu_r=t1["mu_r"],
        l_pole_m=l_pole, l_back_m=pitch * (rc + rs) / 2, a_back_m2=(rs - rc) * la,
        l_rotor_arc_m=pitch * (rr + rj) / 2, l_rotor_radial_m=rj - rr, a_rotor_m2=(rj - rr) * la,
        fs_hz=cfg["controller"]["fs_hz"], substeps=int(cfg["simulation"]["substeps"]),
        u_max_a=cfg["controller"]["u_max_a"],
        pid_coefficients=pid_kernel_coefficients(cfg),
        ss_estimator=ss["estimator"], ss_window=int(ss["window_samples"]), ss_lowpass_hz=ss["lowpass_hz"],
        ss_lowpass_order=int(ss["lowpass_order"]), ss_trend_order=int(ss["trend_order"]),
        ss_gate=float(ss["residual_gate"]), x_bandwidth_hz=cfg["sensors"]["x_bandwidth_hz"],
        **_converters(cfg),
    )
