r"""The 2-DOF self-sensing AMB as a close-the-loop device (:class:`ssamb.device.Device`).

* **Data**: the measured-data format (:data:`ssamb.io.MEASURED_COLUMNS`: references, the x and y
  probes, the self-sensing estimate, four coil currents, two controller outputs), ``.npz`` or
  ``.csv`` with a ``.json`` sidecar; the excitation (a position reference, or a current injection
  that ``meta`` describes and the replay regenerates) drives the replay.
* **Views**: positions (``x_meas``, ``y_ss``, ``y_meas``), the differential and common-mode coil
  currents :math:`d_x = (i_{xpos} - i_{xneg})/2`, :math:`c_x = (i_{xpos} + i_{xneg})/2` (and y),
  the controller outputs. The cost compares the positions and the currents; the controller
  outputs, a digital function of the sensed positions, carry little the positions do not below
  the PWM band and their noise is collinear with them there, but they are logged without noise:
  at the PWM carrier's aliased lines they are compared too (``device_line_views``), where their
  phase carries the loop's timing (a sensor delay) far more precisely than the noisy logged
  positions.
* **Replay**: :func:`ssamb.sim.simulate` with the recorded excitation, the data's start state, the
  effects and the data's logging chain applied to the model's channels; the DSP's converters act
  in the loop, seeded: a replay is one realisation of the loop's noise. The self-sensing
  calibration of a replay is noise-free: a rig's calibration error is a parameter
  (``selfsensing.calibration_*_error``), not a random draw of the model's.
* **Device lines**: the PWM carrier's harmonics aliased by the sampling (:func:`pwm_lines`).
* **Effects**: :mod:`ssamb.sim.effects`, one module each.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from ..device import REPLAY_STREAM, Device, FeatureSpec, Record, Replay
from ..io import DataError

__all__ = ["AMB", "CHANNELS", "VIEWS", "COST_VIEWS", "pwm_lines", "views", "record_from_arrays",
           "DEFAULT_CALIBRATION"]

#: logged channels compared with the model
CHANNELS = ("x_meas", "y_meas", "y_ss", "i_ypos", "i_yneg", "i_xpos", "i_xneg", "u_x", "u_y")
POSITION_CHANNELS = ("x_meas", "y_meas", "y_ss")
CURRENT_CHANNELS = ("i_ypos", "i_yneg", "i_xpos", "i_xneg")
#: derived views: positions, differential (d) and common-mode (c) coil currents, controller outputs
VIEWS = ("x_meas", "y_ss", "y_meas", "d_x", "d_y", "c_x", "c_y", "u_x", "u_y")
#: views compared in the cost: positions and coil currents (module docstring)
COST_VIEWS = ("x_meas", "d_x", "c_x", "y_ss", "y_meas", "d_y", "c_y")

#: the nominal parameters a rig never matches exactly, with their tolerances (config.yaml gives
#: the reasons); used when a config has no ``closeloop.calibration``
DEFAULT_CALIBRATION = {
    "table1.mass_kg": 0.03, "table1.airgap_m": 0.03, "table1.i_bias_a": 0.03, "table1.coil_turns": 0.03,
    "table1.r_coil_ohm": 0.05, "magnetics.iron_conductivity_s_per_m": 0.1, "table1.mu_r": 0.2,
    "table1.v_supply_v": 0.03, "sensors.x_bandwidth_hz": 0.1, "selfsensing.calibration_gain_error": 0.03,
    "selfsensing.calibration_offset_error_m": 1.0e-5,
}


def pwm_lines(f_pwm_hz: float, fs_hz: float, harmonics: int) -> tuple:
    r"""The PWM carrier's first ``harmonics`` harmonics as the sampling sees them (aliased into
    :math:`[0, f_s/2]`: :math:`|k f_{pwm} - f_s\,\mathrm{round}(k f_{pwm}/f_s)|`), distinct, sorted.

    A two-state amplifier's ripple is a periodic waveform at the carrier; its harmonics alias to
    fixed frequencies (30 kHz at 83.3 kHz: 30, 23.3, 6.7, 36.7, 16.6, 13.4, 39.9, 10.1 kHz). Their
    amplitude and phase carry the ripple's shape: the dead time, the supply voltage and the
    coils' inductance, which the low-frequency response barely shows.
    """
    out = set()
    for k in range(1, harmonics + 1):
        f = k * f_pwm_hz
        a = abs(f - fs_hz * round(f / fs_hz))
        if 0 < a < fs_hz / 2:
            out.add(round(a, 6))
    return tuple(sorted(out))


def views(ch: Mapping[str, np.ndarray]) -> dict:
    r"""Derived views of channel arrays (measured, model or residual alike).

    .. math:: d_x = (i_{xpos} - i_{xneg})/2, \quad c_x = (i_{xpos} + i_{xneg})/2

    and the same for y; positions and controller outputs are passed through.
    """
    out = {k: ch[k] for k in ("x_meas", "y_ss", "y_meas", "u_x", "u_y")}
    out["d_x"] = 0.5 * (ch["i_xpos"] - ch["i_xneg"])
    out["d_y"] = 0.5 * (ch["i_ypos"] - ch["i_yneg"])
    out["c_x"] = 0.5 * (ch["i_xpos"] + ch["i_xneg"])
    out["c_y"] = 0.5 * (ch["i_ypos"] + ch["i_yneg"])
    return out


def _excitation_of(meta: Mapping) -> dict:
    exc = meta.get("excitation")
    if exc is None and "kind" in meta and meta.get("kind") not in ("rig", "simulation"):
        exc = meta   # a flat meta: {kind: multisine, ...}
    return dict(exc or {"kind": "unknown"})


def _regenerate_injection(exc: Mapping, fs_hz: float, n: int, source: str) -> dict:
    """Injection arrays of a ``point: current`` excitation, rebuilt from ``meta``."""
    from .api import excitation_arrays

    spec = {k: v for k, v in exc.items()
            if k not in ("axis_seeds", "lines_hz", "samples_per_period", "seed", "duration_s",
                         "fs_hz", "amplitude", "unit")}
    seed = exc.get("seed")
    if seed is None:
        raise DataError(f"{source}: columns 'inj_x'/'inj_y' are missing and meta.excitation has no "
                        "'seed' to regenerate the current injection")
    try:
        _, arrs, _ = excitation_arrays(spec, fs_hz, n / fs_hz, int(seed))
    except ValueError as exc_err:
        raise DataError(f"{source}: columns 'inj_x'/'inj_y' are missing and the injection cannot be "
                        f"regenerated from meta.excitation ({exc_err})") from None
    out = {}
    for k in ("inj_x", "inj_y"):
        a = np.asarray(arrs[k], float)
        if len(a) < n:
            a = np.concatenate([a, np.zeros(n - len(a))])
        out[k] = a[:n]
    return out


def record_from_arrays(arrays: Mapping, meta: Mapping, fs_model_hz: float, source: str = "data") -> Record:
    """A :class:`ssamb.device.Record` of the AMB from validated measured-data arrays and ``meta``.

    The inputs that drive the replay are ``r_x``, ``r_y`` from the file and ``inj_x``, ``inj_y``
    from the file or, if absent, regenerated from ``meta``. When the excitation is periodic (a
    multisine whose ``samples_per_period`` is in ``meta`` and whose samples repeat), the record
    says so (``n_period``), so that the split can fall on whole periods.

    Raises
    ------
    DataError
        ``fs_hz`` differs from the model's controller rate, or a current injection described in
        ``meta`` cannot be recovered.
    """
    fs = float(np.asarray(arrays["fs_hz"]))
    if abs(fs - fs_model_hz) > 1e-6 * fs_model_hz:
        raise DataError(f"{source}: 'fs_hz' = {fs:g} Hz differs from the model's controller rate "
                        f"controller.fs_hz = {fs_model_hz:g} Hz; the replay runs at the controller rate "
                        "(resample the data or use the matching config)")
    ch = {c: np.asarray(arrays[c], dtype=np.float64) for c in CHANNELS}
    n = len(ch["x_meas"])
    exc = _excitation_of(meta)
    inputs = {k: np.asarray(arrays[k], dtype=np.float64) for k in ("r_x", "r_y")}
    if "inj_x" in arrays and "inj_y" in arrays:
        for k in ("inj_x", "inj_y"):
            a = np.asarray(arrays[k], dtype=np.float64)
            if a.shape != (n,) or not np.all(np.isfinite(a)):
                raise DataError(f"{source}: optional column '{k}' must have {n} finite samples")
            inputs[k] = a
    elif exc.get("point") == "current" and exc.get("kind") not in (None, "none", "unknown"):
        inputs.update(_regenerate_injection(exc, fs, n, source))
    else:
        inputs["inj_x"] = np.zeros(n)
        inputs["inj_y"] = np.zeros(n)
    excited, signal = [], {}
    for ax in ("x", "y"):
        r, inj = inputs["r_" + ax], inputs["inj_" + ax]
        if np.ptp(r) > 0:
            excited.append(ax)
            signal[ax] = r
        elif np.ptp(inj) > 0:
            excited.append(ax)
            signal[ax] = inj
    n_period = None
    lines = None
    spp = exc.get("samples_per_period")
    if exc.get("kind") == "multisine" and spp:
        spp = int(spp)
        ok = spp >= 16 and n >= 2 * spp and all(
            np.allclose(s[spp:], s[:-spp], rtol=0, atol=1e-6 * max(np.max(np.abs(s)), 1e-30))
            for s in signal.values())
        if ok:
            n_period = spp
            if exc.get("lines_hz"):
                lines = np.asarray(exc["lines_hz"], float)
    settle = meta.get("settle_s")
    from ..acquisition import validate_acquisition

    acq = validate_acquisition(meta.get("acquisition"), source, fs, key="meta.acquisition", error=DataError)
    return Record(device=AMB.instance(), fs_hz=fs, channels=ch, inputs=inputs, excitation=exc,
                  excited_axes=tuple(excited), signal=signal, n_period=n_period, lines_hz=lines,
                  start=str(meta.get("start", "levitated")),
                  settle_s=None if settle is None else float(settle), acquisition=acq, usable=((0, n),),
                  meta=dict(meta))


class AMB(Device):
    """The 2-DOF self-sensing AMB of the paper (module docstring)."""

    name = "amb"
    channels = CHANNELS
    view_names = VIEWS
    cost_views = COST_VIEWS
    units = {**{c: "m" for c in POSITION_CHANNELS}, **{c: "A" for c in CHANNELS if c not in POSITION_CHANNELS},
             **{v: "A" for v in ("d_x", "d_y", "c_x", "c_y")}}
    error_groups = {"currents": CURRENT_CHANNELS}
    features = FeatureSpec(
        # x: the probe over the coil current; y: the estimate over the coil current, the estimate
        # over the evaluation probe (the sensor path alone: plant changes cancel) and the
        # evaluation probe over the coil current (the plant alone)
        paths={"x": ("x", "x_meas", "d_x"), "y": ("y", "y_ss", "d_y"), "y_sensor": ("y", "y_ss", "y_meas"),
               "y_plant": ("y", "y_meas", "d_y")},
        axis_views={"x": ("x_meas", "d_x", "u_x"), "y": ("y_ss", "y_meas", "d_y", "u_y")},
        counterpart={"x_meas": "y_ss", "d_x": "d_y", "u_x": "u_y", "y_ss": "x_meas", "y_meas": "x_meas",
                     "d_y": "d_x", "u_y": "u_x"},
        line_views=("d_x", "d_y"), ripple_views=("c_x", "c_y", "d_x", "d_y"), band_views=(),
        # the controller outputs, logged without noise, at the PWM carrier's aliased lines: the
        # derivative path passes the sensed ripple there, delayed by the loop's own timing
        device_line_views=("u_x", "u_y"))
    effects_package = "ssamb.sim.effects"
    #: harmonics of the PWM carrier read as device lines
    pwm_harmonics = 8

    @classmethod
    def instance(cls) -> "AMB":
        from ..device import get_device

        return get_device("amb")

    def views(self, ch: Mapping) -> dict:
        return views(ch)

    def load(self, path) -> tuple[dict, dict]:
        from ..io import load_measured

        return load_measured(path)

    def validate(self, arrays: Mapping, source: str) -> None:
        from ..io import validate_measured

        validate_measured(arrays, source)

    def notes(self, arrays: Mapping, meta: Mapping, cfg: Mapping) -> list[str]:
        """Valid but suspicious data (x and y swapped, a channel that never moves or is clipped,
        ...): :func:`ssamb.plausibility.measured_notes`."""
        import logging

        from ..plausibility import check_measured, measured_notes

        try:
            check_measured(arrays, cfg, "data", meta)
        except DataError:
            return []                  # refused by record(), which names the file: no note first
        notes = measured_notes(arrays, meta, cfg)
        for note in notes:             # on stderr (a job's log) at once: before anything is fitted
            logging.getLogger("ssamb.plausibility").warning("note: %s", note)
        return notes

    def record(self, arrays: Mapping, meta: Mapping, cfg: Mapping, source: str) -> Record:
        """The record, after the values no rig produces (positions in mm, currents in mA, nothing
        excited) are refused naming the file and column (:func:`ssamb.plausibility.check_measured`)."""
        from ..plausibility import check_measured

        check_measured(arrays, cfg, source, meta)
        return record_from_arrays(arrays, meta, float(cfg["controller"]["fs_hz"]), source)

    def default_config(self) -> dict:
        from ..config import load_config

        return load_config()

    def load_config(self, path=None) -> dict:
        from ..config import load_config

        return load_config(path)

    def priors(self, cfg: Mapping) -> dict:
        return dict(DEFAULT_CALIBRATION)

    def floors(self, settings) -> dict:
        return {v: settings.floor_position_m if self.unit(v) == "m" else settings.floor_current_a
                for v in self.view_names + self.channels}

    def device_lines_hz(self, cfg: Mapping, fs_hz: float) -> tuple:
        return pwm_lines(float(cfg["table1"]["f_pwm_hz"]), fs_hz, self.pwm_harmonics)

    def replay(self, cfg: Mapping, record: Record, effects: list, n: int, seed: int | None) -> Replay:
        from ..acquisition import apply_acquisition
        from . import simulate

        arrays = {k: v[:n] for k, v in record.inputs.items()}
        res = simulate(cfg, arrays=arrays, effects=effects, start=record.start, settle_s=record.settle_s,
                       progress=False, seed=seed, calibration_noise=False, noise_stream=REPLAY_STREAM, states=False)
        logged = apply_acquisition({c: res.data[c] for c in CHANNELS}, record.acquisition, record.fs_hz)
        return Replay({c: np.asarray(logged[c], float) for c in CHANNELS},
                      res.meta.get("delevitation_s") is not None)

    def validate_effect(self, effect: Mapping, where: str = "effect") -> dict:
        from .effects import validate_effect

        return validate_effect(effect)

    def measured_contact(self, record: Record, cfg: Mapping, settings) -> bool:
        """The measured rotor reached ``contact_fraction`` of the backup bearing's clearance."""
        clearance = float(cfg["table1"]["backup_clearance_m"])
        ch = record.channels
        return bool(np.max(np.hypot(ch["x_meas"], ch["y_meas"])) >= settings.contact_fraction * clearance)
