"""The simulator's Python API: :func:`simulate` and its helpers.

:func:`simulate` runs one experiment in five steps: the excitation (:func:`excitation_arrays`,
:func:`force_arrays`) and the effects become the kernel's drive arrays; the converters' noise
is drawn (:func:`converter_noise`); the levitated equilibrium is computed
(:func:`ssamb.sim.statics.equilibrium`) and DCM self-sensing calibrated on a clamped rotor
(:func:`calibrate_selfsensing`); the compiled kernel runs with a progress bar (:func:`run_kernel`);
and the output is assembled into a :class:`SimResult` whose ``data`` is in the measured-data
format (docs/formats.md) plus the true states (``x_true``, ``y_true``, ``b_*_t``, ``duty_*``,
``contact``, ...). Options other than the configuration travel in a :class:`SimOptions`.
"""
from __future__ import annotations

import hashlib
import logging
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from .. import COILS
from ..config import ConfigError, config_hash
from .dsp import D_REJ, trend_basis
from .effects import apply_effects
from .kernel import LOGGED_NAMES, N_LOGGED, N_OUT, OUT_NAMES, run_chunk
from .normal import standard_normal
from .params import P_CLAMP, P_CLAMP_X, P_CLAMP_Y, P_PID_ON, P_SS_GAIN, P_SS_OFF, AMBParams, amb_params
from .statics import equilibrium, initial_state, network_tables

__all__ = ["SimResult", "SimOptions", "simulate", "equilibrium", "calibrate_selfsensing", "excitation_arrays",
           "force_arrays", "converter_noise", "run_kernel", "delevitation_time"]

log = logging.getLogger("ssamb.sim")


@dataclass
class SimResult:
    """Output of :func:`simulate`.

    Attributes
    ----------
    data : dict of arrays
        Measured-data columns at ``fs_hz`` (``t`` starts at 0 after the pre-roll) and true states.
    meta : dict
        Excitation, seeds, converters, calibration, config hash, delevitation (no wall-clock
        times: the same inputs give the same bytes).
    ripple : dict of arrays
        ``t`` (period start), ``i_max``, ``i_min`` of the ypos current in every PWM period.
    fine : dict of arrays or None
        ``t`` and the four currents at every integration sub-step (``record_fine=True``).
    """

    data: dict
    meta: dict
    ripple: dict
    fine: dict | None = None

    def save(self, path: str | Path) -> None:
        """Write ``data`` (+ ripple, fine) to an NPZ file with a JSON sidecar (atomic)."""
        from ..io import save_npz

        arrays = dict(self.data)
        arrays.update({"ripple_" + k: v for k, v in self.ripple.items()})
        if self.fine is not None:
            arrays.update({"fine_" + k: v for k, v in self.fine.items()})
        save_npz(path, arrays, self.meta)


@dataclass(frozen=True)
class SimOptions:
    """Everything :func:`simulate` takes besides the configuration and the experiment name.

    Attributes
    ----------
    duration_s, excitation, start :
        Override or replace the experiment's fields.
    effects : tuple of mappings
        Effects of the close-the-loop library (:mod:`ssamb.sim.effects`).
    noise : mapping, optional
        ``{position_m, current_a, seed}``: replaces the analog noise levels (and the seed) of the
        converters in the loop (``converters`` section); the quantisation and the computation
        delay stay as configured.
    seed : int, optional
        Base seed of the excitation and the converter noise (default ``cfg['seed']``).
    substeps : int, optional
        Integration sub-steps per controller sample (default ``simulation.substeps``).
    record_fine, track_ripple : bool
        Also return the currents at every sub-step; record the extremes of the ypos current in
        every PWM period (exact, at the edges).
    progress : bool, optional
        Progress bar on stderr (default: runs of a simulated second or more).
    pid_on : bool
        False switches the position controller off (amplifiers keep the bias references).
    clamp_m : (x, y), optional
        Hold the rotor at this position (as on a calibration or magnetics test rig).
    arrays : mapping, optional
        Explicit ``r_x``, ``r_y``, ``inj_x``, ``inj_y`` arrays (replace the excitation).
    effects_base_dir : path, optional
        Directory of relative ``external_force`` files.
    settle_s : float, optional
        Pre-roll before recording (default ``simulation.settle_s``; 0 for a rest start).
    calibration_noise : bool
        False calibrates DCM self-sensing with noise-free converter samples (quantisation
        stays): a calibration without a random error of its own, for a replay whose
        calibration error is a parameter (``selfsensing.calibration_*_error``).
    noise_stream : int
        The converter noise's stream, a key of its seed sequence besides the seed: 0 for an
        experiment; a model's replays of measured data draw from a stream of their own
        (:data:`ssamb.device.REPLAY_STREAM`), so that no replay reproduces the noise of an
        experiment simulated with the same seed (a simulated rig's data are then not one of
        the model's replays, as a real rig's never are).
    states : bool
        False leaves the true states out of ``data`` (``x_true``, ``b_*_t``, ``duty_*``, forces,
        velocities): the logged columns, ``contact`` and ``y_ss_raw`` only, which is all a replay
        of measured data reads.
    """

    duration_s: float | None = None
    excitation: Mapping | None = None
    start: str | None = None
    effects: tuple = field(default_factory=tuple)
    noise: Mapping | None = None
    seed: int | None = None
    substeps: int | None = None
    record_fine: bool = False
    track_ripple: bool = False
    progress: bool | None = None
    pid_on: bool = True
    clamp_m: tuple | None = None
    arrays: Mapping | None = None
    effects_base_dir: str | Path | None = None
    settle_s: float | None = None
    calibration_noise: bool = True
    noise_stream: int = 0
    states: bool = True


# ------------------------------------------------------------------------------------------
def converter_noise(par: AMBParams, n: int, seed_seq: np.random.SeedSequence | int,
                    noise: Mapping | None = None) -> tuple[np.ndarray, np.ndarray]:
    r"""Analog noise of the DSP's converters for ``n`` controller samples.

    Returns ``(noise, npi)``: ``noise`` (rows :data:`ssamb.sim.kernel.NOISE_ROWS`: x probe,
    y probe, the four coil currents) and ``npi`` (4 x PWM periods, the amplifiers' PI current
    samples), white Gaussian with the rms of ``converters.position_noise_m`` and
    ``current_noise_a`` (or of ``noise`` when given, the legacy ``simulate(noise=...)``), drawn in
    that order from ``numpy.random.default_rng(seed_seq)`` (by :func:`ssamb.sim.normal.standard_normal`:
    NumPy's numbers, compiled).

    With ``par.additive_quantisers`` the converters pass their input unrounded
    (:meth:`AMBParams.pack`) and each sample's rounding error is added here instead, a uniform
    draw :math:`q\,u`, :math:`u \sim U[-1/2, 1/2)` (variance :math:`q^2/12`; :math:`q` the step,
    1.22 mA and 0.24 um by default) from a stream of its own (the Gaussian draws unchanged).
    With the analog noise at least :math:`0.4\,q` ahead of the converter (0.5 mA and 0.2 um by
    default), a rounding error is nearly uniform and independent of the signal (the bias of the
    rounding, :math:`(q/\pi)\,e^{-2\pi^2\sigma^2/q^2}`, is 14 uA for the current), so the
    replay is as noisy as the rounding one; for a fixed seed it is a smooth function of every
    parameter, which a derivative-based fit of the mean of replays on common seeds needs.
    """
    sp, si = par.position_noise_m, par.current_noise_a
    if noise:
        sp, si = float(noise.get("position_m", 0.0)), float(noise.get("current_a", 0.0))
        seed_seq = int(noise.get("seed", 0))
    n_per = int(n / par.fs_hz * par.f_pwm_hz) + 4
    if sp == 0.0 and si == 0.0:
        out, out_pi = np.zeros((6, n)), np.zeros((4, n_per))
    else:
        raw, raw_pi = _standard_noise(seed_seq, n, n_per)
        out = np.empty_like(raw)
        np.multiply(raw[:2], sp, out=out[:2])
        np.multiply(raw[2:], si, out=out[2:])
        out_pi = raw_pi * si
    if par.additive_quantisers:
        qx, qi = par.position_step_m, par.current_step_a
        u, u_pi = _rounding_draws(seed_seq, n, n_per)
        out[:2] += qx * u[:2]
        out[2:] += qi * u[2:]
        out_pi = out_pi + qi * u_pi
    return out, out_pi


def _rounding_draws(seed_seq: np.random.SeedSequence | int, n: int, n_per: int) -> tuple[np.ndarray, np.ndarray]:
    """Uniform draws on ``[-1/2, 1/2)``, ``(6 x n, 4 x n_per)``, of a stream of their own: the
    seed sequence's entropy with one more spawn key (the converters' Gaussian draws unchanged)."""
    if isinstance(seed_seq, np.random.SeedSequence):
        sq = np.random.SeedSequence(seed_seq.entropy, spawn_key=(*seed_seq.spawn_key, 0x51A1))
    else:
        sq = np.random.SeedSequence(int(seed_seq), spawn_key=(0x51A1,))
    rng = np.random.default_rng(sq)
    return rng.random((6, n)) - 0.5, rng.random((4, n_per)) - 0.5


#: standard normal draws of recent seeds (replays of one model with several seeds repeat them),
#: kept up to this many bytes
_NOISE_BYTES = 96 * 2**20
_NOISE: dict = {}


def _standard_noise(seed_seq: np.random.SeedSequence | int, n: int, n_per: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit-variance draws ``(6 x n, 4 x n_per)`` of ``default_rng(seed_seq)`` in that order
    (the caller scales copies: the cached arrays are never written)."""
    if isinstance(seed_seq, np.random.SeedSequence):
        key = (repr(seed_seq.entropy), tuple(seed_seq.spawn_key), seed_seq.pool_size, n, n_per)
    else:
        key = (repr(int(seed_seq)), None, None, n, n_per)
    hit = _NOISE.pop(key, None)
    if hit is None:
        rng = np.random.default_rng(seed_seq)
        hit = (standard_normal(rng, (6, n)), standard_normal(rng, (4, n_per)))
    _NOISE[key] = hit
    while len(_NOISE) > 1 and sum(a.nbytes + b.nbytes for a, b in _NOISE.values()) > _NOISE_BYTES:
        _NOISE.pop(next(iter(_NOISE)))
    return hit


def _seed_sequence(cfg: Mapping, seed: int, exc: Mapping, key: int = 0) -> np.random.SeedSequence:
    """Converter noise seed: the base seed, ``converters.seed_offset`` and the excitation's own
    offset (so that every experiment has its own noise), plus ``key`` (the noise stream:
    :attr:`SimOptions.noise_stream`; calibration runs ``1000 + i``)."""
    offsets = [int(exc.get("seed_offset", 0)), int(exc.get("seed", 0))]
    return np.random.SeedSequence([int(seed), int(cfg["converters"]["seed_offset"]), *offsets, key])


def run_kernel(par: AMBParams, packed: np.ndarray, qtab: np.ndarray, start: str, eq: dict | None,
               drive: np.ndarray, noise: np.ndarray, npi: np.ndarray, *, record_fine: bool = False,
               progress: bool = False, desc: str = "simulate", track_ripple: bool = False, states: bool = True):
    """Run the compiled kernel over the drive arrays in 50 ms chunks (progress bar on stderr).

    Returns ``(out, fine, ripple, state)``: ``out`` has the rows
    :data:`~ssamb.sim.kernel.OUT_NAMES`, or with ``states=False`` the rows
    :data:`~ssamb.sim.kernel.LOGGED_NAMES` (the true states not recorded).
    """
    n = drive.shape[1]
    st, ss, z, lad, rings, ss_rings = initial_state(par, start, eq)
    out = np.empty((N_OUT if states else N_LOGGED, n))   # every row of every sample is written (run_chunk)
    fine = np.zeros((13, n * par.substeps if record_fine else 0))
    rip = np.zeros((3, int(n / par.fs_hz * par.f_pwm_hz) + 4 if track_ripple else 0))
    rip_n = 0
    chunk = max(1, int(par.fs_hz * 0.05))
    tb = trend_basis(par.ss_window, par.ss_trend_order)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n / par.fs_hz, unit="s(sim)", desc=desc, file=sys.stderr,
                   bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.2f}/{total:.2f} s simulated "
                              "[{elapsed}<{remaining}]")
    for k0 in range(0, n, chunk):
        k1 = min(n, k0 + chunk)
        rip_n = run_chunk(packed, st, ss, z, lad, rings, ss_rings, tb, qtab, k0, k1, drive, noise, npi,
                          out, fine, rip, rip_n)
        if bar is not None:
            bar.update((k1 - k0) / par.fs_hz)
    if bar is not None:
        bar.close()
    return out, fine, rip[:, :rip_n], (st, ss)


def calibrate_selfsensing(par: AMBParams, packed: np.ndarray, positions_m: Iterable[float],
                          qtab: np.ndarray | None = None, seed_seqs: Iterable | None = None,
                          settle_s: float = 0.005, average_samples: int = 833) -> dict:
    """Calibrate the DCM estimator (gain and offset of eq. (2)) with the rotor clamped.

    At every calibration position the rotor is held (as on a calibration rig), the amplifiers
    are driven at the currents that would levitate it there, and the raw estimate is averaged
    over ``average_samples`` (833 samples at 83.3 kHz = 300 PWM periods = one full cycle of the
    sampling-phase pattern, since 83 300/30 000 = 833/300), with the converters as in the loop
    (noise seeded by ``seed_seqs``, one per position; none if omitted). The least-squares line
    ``y_true = gain * y_raw + offset`` is returned.
    """
    qtab = network_tables(par) if qtab is None else qtab
    positions = np.asarray(list(positions_m), float)
    key = None
    if seed_seqs is None:      # noise-free: a function of its inputs alone, memoised on them
        key = (repr(par), packed.tobytes(), qtab.shape, hashlib.blake2b(np.ascontiguousarray(qtab)).digest(),
               positions.tobytes(), float(settle_s), int(average_samples))
        if key in _CALIBRATIONS:
            _CALIBRATIONS[key] = _CALIBRATIONS.pop(key)     # most recently used last
            return _copy_calibration(_CALIBRATIONS[key])
    seeds = list(seed_seqs) if seed_seqs is not None else [None] * len(positions)
    n = int(round(settle_s * par.fs_hz)) + average_samples
    raws = []
    for ypos, sq in zip(positions, seeds):
        p = packed.copy()
        p[P_CLAMP], p[P_CLAMP_Y], p[P_PID_ON], p[P_SS_GAIN], p[P_SS_OFF] = 1.0, ypos, 0.0, 1.0, 0.0
        eq = equilibrium(par, p, qtab, y_m=ypos)
        drive = np.zeros((6, n))
        drive[2], drive[3] = eq["u_x"], eq["u_y"]
        noise, npi = converter_noise(par, n, sq) if sq is not None else (np.zeros((6, n)), np.zeros((4, n)))
        out, _, _, _ = run_kernel(par, p, qtab, "levitated", eq, drive, noise, npi, states=False)
        raws.append(out[LOGGED_NAMES.index("y_ss_raw"), n - average_samples:].mean())
    raws = np.asarray(raws)
    gain, offset = np.polyfit(raws, positions, 1)
    resid = positions - (gain * raws + offset)
    calib = {"gain": float(gain), "offset_m": float(offset), "positions_m": positions.tolist(),
             "raw_m": raws.tolist(), "max_residual_m": float(np.max(np.abs(resid)))}
    if key is not None:
        _CALIBRATIONS[key] = _copy_calibration(calib)
        while len(_CALIBRATIONS) > _CALIBRATIONS_KEPT:
            _CALIBRATIONS.pop(next(iter(_CALIBRATIONS)))
    return calib


def _equilibrium(par: AMBParams, packed: np.ndarray, qtab: np.ndarray, f_x_n: float, f_y_n: float) -> dict:
    """:func:`equilibrium` at the origin, memoised on its inputs (a close-the-loop analysis replays
    one model with several seeds); the arrays of the result are shared: read them, never write them."""
    key = (repr(par), packed.tobytes(), f_x_n, f_y_n)
    hit = _EQUILIBRIA.pop(key, None)
    if hit is None:
        hit = equilibrium(par, packed, qtab, f_x_n=f_x_n, f_y_n=f_y_n)
    _EQUILIBRIA[key] = hit                  # most recently used last
    while len(_EQUILIBRIA) > _CALIBRATIONS_KEPT:
        _EQUILIBRIA.pop(next(iter(_EQUILIBRIA)))
    return dict(hit)


_EQUILIBRIA: dict = {}
#: noise-free calibrations kept (a close-the-loop analysis replays one model with several seeds)
_CALIBRATIONS: dict = {}
_CALIBRATIONS_KEPT = 64


def _copy_calibration(calib: dict) -> dict:
    return {k: list(v) if isinstance(v, list) else v for k, v in calib.items()}


def excitation_arrays(spec: Mapping, fs_hz: float, duration_s: float | None, seed: int):
    """Reference and injection arrays for an excitation spec (see :func:`ssamb.signals.make_excitation`).

    ``point: position`` drives the position references, ``point: current`` the current
    injection just before the amplifiers; ``axis: both`` drives x with ``seed`` and y with
    ``seed + 7919`` (independent realisations; the same shift applies to a ``seed`` given in
    the spec itself). Returns ``(duration_s, arrays, info)`` where
    ``info`` holds what a data file's ``meta`` must record to regenerate the excitation.
    """
    from .. import signals

    kind = spec.get("kind", "none")
    point = spec.get("point", "position")
    axis = spec.get("axis", "y")
    if point not in ("position", "current"):
        raise ConfigError(f"excitation key 'point': must be 'position' or 'current' (got {point!r})")
    if axis not in ("x", "y", "both"):
        raise ConfigError(f"excitation key 'axis': must be x, y or both (got {axis!r})")
    axes = ("x", "y") if axis == "both" else (axis,)
    sigs = {}
    info: dict[str, Any] = {"seed": seed, "axis_seeds": {}}
    for a_i, ax in enumerate(axes):
        spec_ax = dict(spec)
        if "seed" in spec_ax:   # a seed in the spec takes precedence in make_excitation
            spec_ax["seed"] = int(spec_ax["seed"]) + 7919 * a_i
        try:
            exc = signals.make_excitation(spec_ax, fs_hz, duration_s, seed + 7919 * a_i)
        except ValueError as err:
            raise ConfigError(str(err)) from None
        sigs[ax] = np.asarray(exc.x, float)
        info["axis_seeds"][ax] = exc.seed
        if exc.multisine is not None:
            ms = exc.multisine
            info["lines_hz"] = [float(f) for f in ms.lines_hz]
            info["samples_per_period"] = int(ms.samples_per_period)
    n = len(next(iter(sigs.values())))
    duration_s = n / fs_hz
    z = np.zeros(n)
    arrs = {"r_x": z.copy(), "r_y": z.copy(), "inj_x": z.copy(), "inj_y": z.copy()}
    if kind != "none":
        for ax, x in sigs.items():
            arrs[("r_" if point == "position" else "inj_") + ax] = x
    return duration_s, arrs, info


def force_arrays(spec: Mapping, fs_hz: float, n: int, seed: int):
    """External force on the rotor from an excitation spec (``amplitude_n`` in newtons).

    An identification aid: force pulses move the rotor independently of the controller's
    commands, which makes the amplifier's dependence on position identifiable from closed-loop
    data (with injections alone the positions are causal functions of past commands). The
    force is not a logged signal. ``axis: both`` uses independent realisations per axis.
    Returns ``(f_x, f_y, info)``.
    """
    from .. import signals

    spec = dict(spec)
    if "amplitude_n" not in spec:
        raise ConfigError("force excitation: key 'amplitude_n' missing")
    axis = spec.pop("axis", "y")
    spec["amplitude_a"] = spec.pop("amplitude_n")   # make_excitation's amplitude (unit label only)
    spec.pop("point", None)
    axes = ("x", "y") if axis == "both" else (axis,)
    out = {"x": np.zeros(n), "y": np.zeros(n)}
    for a_i, ax in enumerate(axes):
        sp = dict(spec)
        if "seed" in sp:
            sp["seed"] = int(sp["seed"]) + 7919 * a_i
        try:
            exc = signals.make_excitation(sp, fs_hz, n / fs_hz, seed + 104729 + 7919 * a_i)
        except ValueError as err:
            raise ConfigError(f"force excitation: {err}") from None
        out[ax] = np.asarray(exc.x, float)[:n]
    return out["x"], out["y"], {"axis": axis, **{k: v for k, v in spec.items()}}


def delevitation_time(t: np.ndarray, contact: np.ndarray, start: str = "levitated") -> float | None:
    """First time the rotor reaches the backup bearing clearance after having levitated.

    For a ``rest`` start the rotor must first lift off; returns None if it never delevitates.
    """
    contact = np.asarray(contact) > 0.5
    if start == "rest":
        free = np.flatnonzero(~contact)
        if free.size == 0:
            return None
        contact = contact.copy()
        contact[: free[0]] = False
    idx = np.flatnonzero(contact)
    return float(t[idx[0]]) if idx.size else None


# ---- simulate() and its steps ------------------------------------------------------------
def _experiment(cfg: Mapping, experiment: str | None, opts: SimOptions) -> dict:
    """The experiment's fields (duration, start, excitation, force) with the options applied."""
    if experiment is not None and experiment not in cfg["experiments"]:
        raise ConfigError(f"experiment '{experiment}': not in config (known: {', '.join(cfg['experiments'])})")
    exp = dict(cfg["experiments"][experiment]) if experiment is not None else {}
    if opts.duration_s is not None:
        exp["duration_s"] = opts.duration_s
    if opts.excitation is not None:
        exp["excitation"] = dict(opts.excitation)
    if opts.start is not None:
        exp["start"] = opts.start
    exp.setdefault("start", "levitated")
    exp.setdefault("excitation", {"kind": "none"})
    exp.setdefault("duration_s", None)
    return exp


#: memory a simulation holds per controller sample (bytes): the kernel's outputs, the drive and
#: noise arrays and the saved file's copies (about 380 measured on a 2 s run), with a margin
BYTES_PER_SAMPLE = 450


def _available_memory() -> int | None:
    """Memory available to a new allocation (bytes): ``MemAvailable`` of ``/proc/meminfo`` (Linux),
    else the free physical pages; None when the system tells neither."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        import os

        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(n_samples: int, fs_hz: float, experiment: str | None) -> None:
    """Raise :class:`ssamb.config.ConfigError` before a simulation of ``n_samples`` controller
    samples (pre-roll included) that needs more memory than is available
    (:data:`BYTES_PER_SAMPLE` each), naming the experiment's duration."""
    need = n_samples * BYTES_PER_SAMPLE
    avail = _available_memory()
    if avail is not None and need > avail:
        name = f"experiment '{experiment}'" if experiment else "the simulation"
        raise ConfigError(f"{name}: duration_s with the pre-roll simulation.settle_s is {n_samples / fs_hz:.4g} s "
                          f"({n_samples:.3g} samples), which needs about {need / 2**30:.3g} GiB of memory; "
                          f"{avail / 2**30:.3g} GiB are available (a shorter duration_s or a larger machine)")


def _drive(cfg: Mapping, par: AMBParams, exp: dict, opts: SimOptions, seed: int, experiment: str | None):
    """Drive arrays (references, injections, forces) over pre-roll and record, kernel overrides."""
    fs = par.fs_hz
    if opts.arrays is not None:
        n = len(next(iter(opts.arrays.values())))
        sig = {k: np.asarray(opts.arrays.get(k, np.zeros(n)), float) for k in ("r_x", "r_y", "inj_x", "inj_y")}
        info = {}
    else:
        _, sig, info = excitation_arrays(exp["excitation"], fs, exp["duration_s"], seed)
    n = len(sig["r_x"])
    if n < 1:
        raise ConfigError(f"experiment '{experiment}': duration {exp['duration_s']} s gives no samples")
    settle = cfg["simulation"]["settle_s"] if opts.settle_s is None else opts.settle_s
    if exp["start"] == "rest":
        settle = 0.0
    n_settle = int(round(settle * fs))
    check_memory(n_settle + n, fs, experiment)
    t_all = (np.arange(n_settle + n) - n_settle) / fs
    ov, f_x, f_y = apply_effects(opts.effects, np.maximum(t_all, 0.0), opts.effects_base_dir)
    force_info = None
    if exp.get("force"):
        fxs, fys, force_info = force_arrays(exp["force"], fs, n, seed)
        f_x = f_x + np.concatenate([np.zeros(n_settle), fxs])
        f_y = f_y + np.concatenate([np.zeros(n_settle), fys])
    drive = np.empty((6, n_settle + n))
    for row, key in enumerate(("r_x", "r_y", "inj_x", "inj_y")):
        drive[row, :n_settle] = sig[key][0] if key.startswith("r_") else 0.0
        drive[row, n_settle:] = sig[key]
    drive[4], drive[5] = f_x, f_y
    return drive, sig, {"settle_s": settle, "n_settle": n_settle, "info": info, "force_info": force_info}, ov


def _packed(par: AMBParams, ov: Mapping, opts: SimOptions) -> np.ndarray:
    packed = par.pack(**ov)
    if not opts.pid_on:
        packed[P_PID_ON] = 0.0
    if opts.clamp_m is not None:
        packed[P_CLAMP] = 1.0
        packed[P_CLAMP_X], packed[P_CLAMP_Y] = float(opts.clamp_m[0]), float(opts.clamp_m[1])
    return packed


def _assemble(par: AMBParams, out, fine, rip, drive, sig, run: dict, record_fine: bool):
    """Measured-data columns (recorded part only), ripple record and fine output."""
    settle, n_settle = run["settle_s"], run["n_settle"]
    sl = slice(n_settle, drive.shape[1])
    names = OUT_NAMES if out.shape[0] == N_OUT else LOGGED_NAMES
    data = {name: out[i, sl] for i, name in enumerate(names)}   # views, no copies
    data["t"] = data["t"] - settle
    data.update({k: sig[k] for k in ("r_x", "r_y", "inj_x", "inj_y")})
    data["f_ext_x_n"] = drive[4, sl]
    data["f_ext_y_n"] = drive[5, sl]
    data["fs_hz"] = np.asarray(par.fs_hz)
    keep = rip[0] - settle >= 0
    ripple = {"t": rip[0][keep] - settle, "i_max": rip[1][keep], "i_min": rip[2][keep]}
    fine_d = None
    if record_fine:
        fsl = slice(n_settle * par.substeps, drive.shape[1] * par.substeps)
        fine_d = {"t": fine[0, fsl] - settle}
        for j, cname in enumerate(COILS):
            fine_d["i_" + cname] = fine[1 + j, fsl]
            fine_d["phi_" + cname] = fine[5 + j, fsl]
            fine_d["v_" + cname] = fine[9 + j, fsl]
    return data, ripple, fine_d


def simulate(cfg: Mapping, experiment: str | None = None, options: SimOptions | None = None,
             **kwargs) -> SimResult:
    """Simulate the nonlinear self-sensing AMB.

    Parameters
    ----------
    cfg : mapping
        Validated configuration (:func:`ssamb.config.load_config`).
    experiment : str, optional
        Name of an experiment in ``cfg['experiments']`` (duration, start and excitation).
    options : SimOptions, optional
        Run options; keyword arguments (the fields of :class:`SimOptions`) override them.

    Returns
    -------
    SimResult
        ``data``: the measured-data columns (``docs/formats.md``) and the true states, sampled
        at the controller rate; ``meta``: the experiment, its excitation, the equilibrium, the
        self-sensing calibration, the delevitation time (None when the rotor stays levitated),
        seeds and the config hash. ``save(path)`` writes both.

    Raises
    ------
    ssamb.errors.InputError
        An experiment, effect or option that cannot be simulated, named in one line.

    Examples
    --------
    >>> from ssamb.config import load_config
    >>> from ssamb.sim import simulate
    >>> res = simulate(load_config(), "levitate", progress=False)   # lift-off from the backup bearing
    >>> res.meta["delevitation_s"] is None                           # it stays levitated
    True
    >>> res.save("levitate.npz")                                     # levitate.npz + levitate.json
    """
    opts = replace(options or SimOptions(), **kwargs)
    if not isinstance(opts.effects, tuple):
        opts = replace(opts, effects=tuple(opts.effects))
    t_wall = time.perf_counter()
    exp = _experiment(cfg, experiment, opts)
    c = cfg if opts.substeps is None else {**cfg, "simulation": {**cfg["simulation"], "substeps": int(opts.substeps)}}
    par = amb_params(c)
    seed = int(cfg["seed"]) if opts.seed is None else int(opts.seed)   # make_excitation adds the seed_offset
    drive, sig, run, ov = _drive(cfg, par, exp, opts, seed, experiment)
    packed = _packed(par, ov, opts)
    qtab = network_tables(par)
    noise, npi = converter_noise(par, drive.shape[1], _seed_sequence(cfg, seed, exp["excitation"], opts.noise_stream),
                                 opts.noise)
    # equilibrium for the static part of the load at t = 0 (the pre-roll settles the rest)
    eq = _equilibrium(par, packed, qtab, float(drive[4, 0]), float(drive[5, 0]))
    calib = None
    if cfg["selfsensing"]["calibrate"]:
        positions = cfg["selfsensing"]["calibration_positions_m"]
        seeds = ([_seed_sequence(cfg, seed, exp["excitation"], 1000 + i) for i in range(len(positions))]
                 if opts.calibration_noise else None)
        calib = calibrate_selfsensing(par, par.pack(**{k: v for k, v in ov.items() if k in ("XCOUP", "DEADTIME")}),
                                      positions, qtab, seeds)
        packed[P_SS_GAIN], packed[P_SS_OFF] = calib["gain"], calib["offset_m"]
    # a rig's calibration is never exact: its error (1 and 0 by default) on top of the procedure's result
    packed[P_SS_GAIN] *= float(cfg["selfsensing"]["calibration_gain_error"])
    packed[P_SS_OFF] += float(cfg["selfsensing"]["calibration_offset_error_m"])
    dur = (drive.shape[1] - run["n_settle"]) / par.fs_hz
    progress = dur >= 1.0 if opts.progress is None else opts.progress
    out, fine, rip, (_, ss) = run_kernel(par, packed, qtab, exp["start"], eq, drive, noise, npi,
                                   record_fine=opts.record_fine, progress=progress,
                                   track_ripple=opts.track_ripple, desc=f"simulate {experiment or ''}".strip(),
                                   states=opts.states)
    data, ripple, fine_d = _assemble(par, out, fine, rip, drive, sig, run, opts.record_fine)
    meta = {
        "kind": "simulation", "experiment": experiment,
        "excitation": {**dict(exp["excitation"]), **run["info"]}, "force_excitation": run["force_info"],
        "start": exp["start"], "duration_s": dur, "fs_hz": par.fs_hz, "seed": seed, "settle_s": run["settle_s"],
        "substeps": par.substeps, "effects": [dict(e) for e in opts.effects],
        "noise": dict(opts.noise) if opts.noise else None,
        "converters": dict(cfg["converters"]), "selfsensing_estimator": par.ss_estimator,
        "selfsensing_calibration": calib, "selfsensing_windows_rejected": int(ss[D_REJ]),
        "equilibrium": {"u_x": eq["u_x"], "u_y": eq["u_y"], "currents_a": eq["currents_a"].tolist()},
        "delevitation_s": delevitation_time(data["t"], data["contact"], exp["start"]),
        "config_hash": config_hash(cfg), "coils": list(COILS),
    }
    timing = f"simulate {experiment or '(arrays)'}: {dur:.3f} s simulated in {time.perf_counter() - t_wall:.3f} s wall"
    log.info(timing)
    if progress:            # timings go to stderr (the workflow's logs), never into the result
        print(timing, file=sys.stderr)
    return SimResult(data=data, meta=meta, ripple=ripple, fine=fine_d)
