r"""A simulated rig: a model that is not the nominal one, with undeclared effects, seen through a
logging chain.

``python -m ssamb rig SCENARIO.yaml --out DATA.npz`` (:func:`run_scenario`) reads a scenario
file (docs/formats.md, "Scenario file"), simulates the nonlinear AMB with the rig's own
parameters and the scenario's effects, passes the logged channels through the logging chain
(anti-alias filter, then logging noise) and writes **only what a rig logs**: the measured-data
format (plus the optional columns ``inj_x``, ``inj_y``) and a ``meta`` that describes the
excitation (kind, parameters, seeds, injection point, axis) and the logging chain, but never the
effects, the overrides or the noise.

Scenario file
-------------
.. code-block:: yaml

    config: config.yaml            # nominal parameters, relative to the scenario file
    overrides:                     # the rig's own physics (dotted config keys): never in meta
      table1.mass_kg: 4.02
      magnetics.iron_conductivity_s_per_m: 1.8e+6
      converters.current_adc_bits: 12
      converters.current_noise_a: 1.0e-3
    experiment: {kind: multisine, point: position, axis: both, amplitude_m: 3.0e-5,
                 f_min_hz: 5, f_max_hz: 100, f_resolution_hz: 5, periods: 10, seed: 3}
    effects:                       # what the rig has and the model does not
      - {name: sensor_delay, axis: both, delay_s: 2.4e-5}
    acquisition: {antialias_hz: 10000.0, order: 4}   # the logger's anti-alias filter: in meta
    noise: {position_m: 2.0e-8, current_a: 3.0e-4, seed: 11}

Optional top-level keys: ``overrides``, ``effects``, ``acquisition``, ``noise``,
``duration_s`` (required unless the excitation is a multisine or a sweep, which define their
own length), ``start`` (``levitated``, the default, or ``rest``), ``description`` and
``output: {dtype: float32}`` (store the logged signals in single precision, e.g. to keep a
shipped data set small; ``t`` and ``fs_hz`` stay double; the default is ``float64``). The file
is a compressed NPZ (``numpy.load`` reads it). ``experiment`` may also be the name of an
experiment in the config. Effects follow the effect library (:mod:`ssamb.sim.effects`); an
``external_force`` file is relative to the scenario file.

The rig's own parameters
------------------------
``overrides`` maps dotted config keys to values (:func:`ssamb.config.apply_overrides`): the
rig's configuration is the ``config`` file's with them applied and validated like any config;
the analysis, which reads the nominal config, never sees them (``meta.config_hash`` is the
nominal config's). A mapping value replaces the whole section it names (``converters: {...}``
must then hold every key of the section); to change one key, name it with its dotted key. A key
the config lacks, or a value it rejects: ``<file>: key 'overrides.<key>': ...``.

Noise and quantisation inside the loop are the config's converters (``converters.*``: analog
noise, ADC bits, one sample of computation delay), set through ``overrides``; their noise is
seeded from the excitation seed and ``converters.seed_offset``. The levels the default loop
tolerates are measured by ``bench/converter_tolerance.py`` (README, "The simulated rig").

The logging chain (a decision, see README "Close the loop with your rig data")
------------------------------------------------------------------------------
``acquisition`` is the logger's anti-alias filter (:mod:`ssamb.acquisition`): a causal
Butterworth low-pass on the logged analog channels ``x_meas, y_meas, i_ypos, i_yneg, i_xpos,
i_xneg``; the DSP's digital values (``y_ss, u_x, u_y, r_x, r_y, inj_x, inj_y``) pass
unfiltered. A user knows the logging chain, so ``meta["acquisition"]`` carries the normalised
specification; without ``acquisition`` (or with ``{}``) nothing is filtered and ``meta`` has no
``acquisition`` key (a reader treats a missing key and ``null`` alike: no filter).

``noise`` is **data-acquisition** noise (the logger's own ADC, after the filter): independent
white Gaussian sequences added to the *logged* channels only,

.. math::

    x_{meas} \mathrel{+}= n_1,\; y_{meas} \mathrel{+}= n_2,\; y_{ss} \mathrel{+}= n_3,
    \quad n_{1..3} \sim \mathcal N(0, \sigma_p^2), \qquad
    i_{c} \mathrel{+}= m_c,\; m_c \sim \mathcal N(0, \sigma_i^2)\; (c = ypos, yneg, xpos, xneg),

drawn in that order (a ``7 x n`` array) from ``numpy.random.default_rng(noise.seed)``. The
controller outputs ``u_x``, ``u_y`` are digital values inside the DSP and are logged without
noise. The loop itself runs with the converters of the rig's config (above), whatever the
logging noise.

Seeds: the excitation seed is the experiment's ``seed`` (default: the config's ``seed``); with
``axis: both`` the y axis uses ``seed + 7919`` (an independent realisation).
"""
from __future__ import annotations

import math
import numbers
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .acquisition import apply_acquisition, validate_acquisition
from .errors import InputError, check_finite
from .io import MEASURED_COLUMNS, versions

__all__ = ["ScenarioError", "load_scenario", "rig_data", "run_scenario", "NOISE_KEYS"]

#: top-level keys of a scenario file: (required, optional)
_TOP_REQUIRED = ("experiment",)
_TOP_OPTIONAL = ("config", "overrides", "effects", "noise", "acquisition", "duration_s", "start", "description",
                 "output")
#: keys of the ``output`` mapping and their allowed values
_OUTPUT_DTYPES = ("float64", "float32")
#: keys of the ``noise`` mapping
NOISE_KEYS = ("position_m", "current_a", "seed")
#: logged channels that receive position / current noise, in the order of the noise draws
_POSITION_CHANNELS = ("x_meas", "y_meas", "y_ss")
_CURRENT_CHANNELS = ("i_ypos", "i_yneg", "i_xpos", "i_xneg")


class ScenarioError(InputError):
    """A scenario file is invalid; the message names the file and the key."""


def _number(where: str, value: Any, *, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(float(value)):
        raise ScenarioError(f"{where}: must be a finite number (got {value!r})")
    if nonneg and float(value) < 0:
        raise ScenarioError(f"{where}: must be >= 0 (got {value!r})")
    return float(value)


def _validate_noise(src: str, noise: Any) -> dict | None:
    if noise is None:
        return None
    if not isinstance(noise, Mapping):
        raise ScenarioError(f"{src}: key 'noise' must be a mapping with {', '.join(NOISE_KEYS)}")
    unknown = [k for k in noise if k not in NOISE_KEYS]
    if unknown:
        raise ScenarioError(f"{src}: key 'noise.{unknown[0]}' is unknown (allowed: {', '.join(NOISE_KEYS)})")
    out = {k: _number(f"{src}: key 'noise.{k}'", noise.get(k, 0.0), nonneg=True)
           for k in ("position_m", "current_a")}
    if out["position_m"] > 0 or out["current_a"] > 0:
        if "seed" not in noise:
            raise ScenarioError(f"{src}: key 'noise.seed' is missing (required when noise is nonzero)")
    seed = noise.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or int(seed) < 0:
        raise ScenarioError(f"{src}: key 'noise.seed' must be an integer >= 0 (got {seed!r})")
    out["seed"] = int(seed)
    return out


def _violated_override(message: str, keys: list[str]) -> str | None:
    """The override a config violation concerns: the violated key itself, the section holding it,
    or the first override the message names (a cross-key rule); None if none."""
    violated = message.split("'")[1] if message.startswith("config key '") else ""
    for k in keys:
        if violated == k or violated.startswith(k + "."):
            return k
    return next((k for k in keys if k in message), None)


def _rig_config(src: str, cfg: dict, overrides: Any) -> dict:
    """The rig's own configuration: ``cfg`` with the scenario's ``overrides`` applied, validated.

    Each key is a dotted config key (:func:`ssamb.config.apply_overrides`); a mapping value
    replaces the whole section it names. A key the config lacks, a value the schema or a
    physical rule rejects: one line naming ``overrides.<key>``.
    """
    from .config import ConfigError, apply_overrides, get, validate_config

    if overrides is None:
        return cfg
    if not isinstance(overrides, Mapping):
        raise ScenarioError(f"{src}: key 'overrides': must be a mapping of dotted config keys to values")
    keys = [str(k) for k in overrides]
    for k in keys:
        try:
            get(cfg, k)
        except ConfigError:
            raise ScenarioError(f"{src}: key 'overrides.{k}': not a key of the config "
                                "(dotted, e.g. table1.mass_kg)") from None
    rig = apply_overrides(cfg, {str(k): v for k, v in overrides.items()})
    try:
        validate_config(rig)
    except ConfigError as exc:
        msg = str(exc)
        k = _violated_override(msg, keys)
        if k is not None and msg.startswith(f"config key '{k}': "):
            msg = msg[len(f"config key '{k}': "):]
        where = "overrides" if k is None else f"overrides.{k}"
        raise ScenarioError(f"{src}: key '{where}': {msg}") from None
    return rig


def _read_scenario(path: Path) -> tuple[str, dict]:
    """Read a scenario file and check its top-level keys.

    Parameters
    ----------
    path : Path
        The scenario file.

    Returns
    -------
    src : str
        The file name the messages start with.
    sc : dict
        The file's mapping, every number finite, the required keys present, no unknown key.
    """
    from .config import read_yaml_mapping

    src = str(path)
    if not path.exists():
        raise ScenarioError(f"{src}: scenario file not found")
    sc = read_yaml_mapping(path, src, ScenarioError)
    check_finite(sc, src, ScenarioError)
    for k in _TOP_REQUIRED:
        if k not in sc:
            raise ScenarioError(f"{src}: key '{k}' is missing (required)")
    unknown = [k for k in sc if k not in _TOP_REQUIRED + _TOP_OPTIONAL]
    if unknown:
        raise ScenarioError(f"{src}: key '{unknown[0]}' is unknown (allowed: "
                            f"{', '.join(_TOP_REQUIRED + _TOP_OPTIONAL)})")
    return src, sc


def _scenario_configs(src: str, sc: Mapping, base: Path) -> tuple[dict, dict]:
    """The nominal config (key ``config``, relative to ``base``) and the rig's own.

    Returns
    -------
    nominal : dict
        The config the scenario names (the default ``config.yaml`` without the key), validated.
    cfg : dict
        ``nominal`` with the scenario's ``overrides`` (:func:`_rig_config`), validated.
    """
    from .config import ConfigError, load_config

    cfg_path = sc.get("config")
    if cfg_path is not None:
        cfg_path = Path(cfg_path)
        if not cfg_path.is_absolute():
            cfg_path = base / cfg_path
    try:
        nominal = load_config(cfg_path)
    except ConfigError as exc:
        raise ScenarioError(f"{src}: key 'config': {exc}") from None
    return nominal, _rig_config(src, nominal, sc.get("overrides"))


def _excitation_spec(src: str, exp: Any, cfg: Mapping) -> tuple[dict, int, Mapping | None]:
    """The excitation of key ``experiment``: an experiment name of ``cfg`` or an inline spec.

    Returns
    -------
    spec : dict
        The excitation spec without ``seed`` and ``seed_offset``.
    seed : int
        The excitation seed: the spec's ``seed`` (default: the config's) plus ``seed_offset``.
    named : Mapping or None
        The config's experiment (for its ``duration_s`` and ``start``), None for an inline spec.
    """
    if isinstance(exp, str):
        if exp not in cfg["experiments"]:
            raise ScenarioError(f"{src}: key 'experiment': '{exp}' is not an experiment of the config "
                                f"(known: {', '.join(cfg['experiments'])})")
        named = cfg["experiments"][exp]
        spec = dict(named["excitation"])
        seed = int(spec.pop("seed", cfg["seed"])) + int(spec.pop("seed_offset", 0))
        return spec, seed, named
    if isinstance(exp, Mapping):
        spec = dict(exp)
        if "kind" not in spec:
            raise ScenarioError(f"{src}: key 'experiment.kind' is missing (none, pulses, multisine, sweep, step)")
        seed = spec.pop("seed", cfg["seed"])
        if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or int(seed) < 0:
            raise ScenarioError(f"{src}: key 'experiment.seed' must be an integer >= 0 (got {seed!r})")
        return spec, int(seed) + int(spec.pop("seed_offset", 0)), None
    raise ScenarioError(f"{src}: key 'experiment' must be a mapping (an excitation spec) or an experiment name")


def _scenario_experiment(src: str, sc: Mapping, cfg: Mapping) -> tuple[dict, int, float | None, str]:
    """The scenario's experiment, checked: ``(spec, seed, duration_s, start)``.

    ``duration_s`` and ``start`` default to the named experiment's; ``spec`` gets ``point:
    position`` and ``axis: y`` unless it says otherwise; ``duration_s`` may be None only for a
    multisine or a sweep (their length follows from the spec). The excitation itself (named keys,
    ranges) is checked by the signal generator (:func:`ssamb.signals.make_excitation`).
    """
    spec, seed, named = _excitation_spec(src, sc["experiment"], cfg)
    duration = sc.get("duration_s")
    start = sc.get("start")
    if named is not None:
        duration = named["duration_s"] if duration is None else duration
        start = named["start"] if start is None else start
    spec.setdefault("point", "position")
    spec.setdefault("axis", "y")
    if duration is not None:
        duration = _number(f"{src}: key 'duration_s'", duration, nonneg=True)
        if duration <= 0:
            raise ScenarioError(f"{src}: key 'duration_s' must be > 0")
    elif spec["kind"] not in ("multisine", "sweep"):
        raise ScenarioError(f"{src}: key 'duration_s' is missing (required for excitation kind '{spec['kind']}')")
    start = start or "levitated"
    if start not in ("levitated", "rest"):
        raise ScenarioError(f"{src}: key 'start' must be 'levitated' or 'rest' (got {start!r})")
    from .signals import make_excitation

    try:
        make_excitation(spec, float(cfg["controller"]["fs_hz"]), duration, seed)
    except ValueError as exc:
        text = str(exc)
        if text.startswith("duration_s: "):
            raise ScenarioError(f"{src}: key 'duration_s': {text[len('duration_s: '):]}") from None
        raise ScenarioError(f"{src}: key 'experiment': {text}") from None
    return spec, seed, duration, start


def _scenario_effects(src: str, effects_raw: Any, base: Path) -> list[dict]:
    """The effects of key ``effects``, each validated and flat
    (:func:`ssamb.sim.effects.validate_effect`); an ``external_force`` file is made absolute,
    relative to ``base``, and read and checked here
    (:func:`ssamb.sim.effects.external_force.read_force_file`),
    before any simulation."""
    from .sim.effects import EffectError, validate_effect
    from .sim.effects.external_force import read_force_file

    if not isinstance(effects_raw, list):
        raise ScenarioError(f"{src}: key 'effects' must be a list of effects")
    effects = []
    for i, e in enumerate(effects_raw):
        if not isinstance(e, Mapping):
            raise ScenarioError(f"{src}: key 'effects[{i}]' must be a mapping with 'name' and its parameters")
        try:
            flat = validate_effect(e)
        except EffectError as exc:
            raise ScenarioError(f"{src}: key 'effects[{i}]': {exc}") from None
        if flat["name"] == "external_force" and "file" in flat:
            f = Path(flat["file"])
            f = f if f.is_absolute() else base / f
            if not f.exists():
                raise ScenarioError(f"{src}: key 'effects[{i}].file': '{f}' not found")
            try:
                read_force_file(f)
            except InputError as exc:
                raise ScenarioError(f"{src}: key 'effects[{i}].file': {exc}") from None
            flat["file"] = str(f)
        effects.append(flat)
    return effects


def _check_loads(src: str, effects: list[dict], cfg: Mapping) -> None:
    """The forces of the effects at t = 0 (where the simulation starts from the static
    equilibrium that carries them, with the weight) against the bearing's load capacity
    (:func:`ssamb.config.load_capacity_n`, an upper bound): an effect the bearing could never
    carry is named by its key before anything is simulated."""
    from .config import load_capacity_n
    from .sim.effects import apply_effects

    cap = load_capacity_n(cfg)
    weight = float(cfg["weight_share"]) * float(cfg["table1"]["mass_kg"]) * float(cfg["gravity_m_per_s2"])
    total = np.array([0.0, -weight])
    for i, e in enumerate(effects):
        _, fx, fy = apply_effects([e], np.zeros(1))
        f = np.array([fx[0], fy[0]])
        total += f
        if np.hypot(*f) > cap:
            hint = ""
            if e["name"] == "unbalance":
                hint = (f"; m e w^2 at speed_hz = {e['speed_hz']:g} Hz with mass_ecc_kgm = {e['mass_ecc_kgm']:g} kg m"
                        f" (a speed in rpm? {e['speed_hz']:g} rpm = {e['speed_hz'] / 60:.4g} Hz)")
            raise ScenarioError(f"{src}: key 'effects[{i}]': effect '{e['name']}' pulls {np.hypot(*f):.4g} N at "
                                f"t = 0, more than the bearing's load capacity {cap:.4g} N (an upper bound; the "
                                f"simulation starts from the static equilibrium that carries it){hint}")
    if max(abs(total)) > cap:
        raise ScenarioError(f"{src}: key 'effects': the effects' forces at t = 0 with the weight load the bearing "
                            f"with ({total[0]:.4g}, {total[1]:.4g}) N, more than its load capacity {cap:.4g} N "
                            "(an upper bound; the simulation starts from the static equilibrium that carries it)")


def _output_dtype(src: str, output: Any) -> str:
    """The sample type of key ``output`` (a mapping whose only key is ``dtype``; default float64)."""
    if not isinstance(output, Mapping) or any(k != "dtype" for k in output):
        raise ScenarioError(f"{src}: key 'output' must be a mapping with the only key 'dtype'")
    dtype = output.get("dtype", "float64")
    if dtype not in _OUTPUT_DTYPES:
        raise ScenarioError(f"{src}: key 'output.dtype' must be one of {', '.join(_OUTPUT_DTYPES)} (got {dtype!r})")
    return dtype


def load_scenario(path: str | Path) -> dict:
    """Read and validate a scenario file.

    Returns a dict with ``cfg`` (the rig's own config: the nominal one with the scenario's
    ``overrides``, validated), ``nominal_config_hash`` (of the config without them),
    ``excitation`` (a spec without its seed), ``seed`` (the excitation seed), ``duration_s``,
    ``start``, ``effects`` (validated, flat), ``noise`` (or None), ``acquisition`` (normalised,
    ``{}`` for none), ``dtype`` (of the written samples), ``description`` (or None) and
    ``base_dir`` (the scenario's directory).

    Raises
    ------
    ScenarioError
        Unknown or missing keys, an unknown effect or a missing effect parameter, an override
        of a key the config lacks or to a value it rejects, bad noise or acquisition; the
        message names the file and the key.
    """
    from .config import config_hash

    path = Path(path)
    src, sc = _read_scenario(path)
    base = path.resolve().parent
    nominal, cfg = _scenario_configs(src, sc, base)
    spec, seed, duration, start = _scenario_experiment(src, sc, cfg)
    effects = _scenario_effects(src, sc.get("effects") or [], base)
    _check_loads(src, effects, cfg)
    noise = _validate_noise(src, sc.get("noise"))
    acquisition = validate_acquisition(sc.get("acquisition"), src, float(cfg["controller"]["fs_hz"]),
                                       error=ScenarioError)
    dtype = _output_dtype(src, sc.get("output") or {})
    return {"cfg": cfg, "dtype": dtype, "excitation": spec, "seed": seed, "duration_s": duration, "start": start,
            "effects": effects, "noise": noise, "acquisition": acquisition, "base_dir": str(base),
            "nominal_config_hash": config_hash(nominal),
            "description": sc.get("description")}


def add_logging_noise(data: Mapping[str, np.ndarray], noise: Mapping | None) -> dict:
    """Return the logged channels with data-acquisition noise added (see module docstring)."""
    out = {k: np.asarray(v, float).copy() for k, v in data.items()}
    if not noise:
        return out
    n = len(out["t"])
    rng = np.random.default_rng(int(noise["seed"]))
    draws = rng.standard_normal((len(_POSITION_CHANNELS) + len(_CURRENT_CHANNELS), n))
    for row, c in enumerate(_POSITION_CHANNELS):
        out[c] = out[c] + noise["position_m"] * draws[row]
    for row, c in enumerate(_CURRENT_CHANNELS, start=len(_POSITION_CHANNELS)):
        out[c] = out[c] + noise["current_a"] * draws[row]
    return out


def rig_data(scenario: Mapping, progress: bool = False) -> tuple[dict, dict]:
    """Simulate a validated scenario (:func:`load_scenario`); return ``(arrays, meta)`` as logged.

    ``arrays`` holds exactly the measured-data columns, ``fs_hz``, ``inj_x`` and ``inj_y``: the
    simulated channels through the logging chain (:func:`ssamb.acquisition.apply_acquisition`),
    then the logging noise (:func:`add_logging_noise`). ``meta`` describes the excitation, the
    start and the logging chain (``acquisition``, only when the scenario has one), never the
    effects, the overrides nor the noise; its ``config_hash`` is the nominal config's.
    """
    from .sim import simulate

    cfg = scenario["cfg"]
    res = simulate(cfg, duration_s=scenario["duration_s"], excitation=scenario["excitation"],
                   start=scenario["start"], effects=scenario["effects"], seed=scenario["seed"],
                   progress=progress, effects_base_dir=scenario["base_dir"])
    keep = list(MEASURED_COLUMNS) + ["inj_x", "inj_y"]
    fs_hz = float(res.data["fs_hz"])
    acquisition = scenario.get("acquisition") or {}
    filtered = apply_acquisition({k: res.data[k] for k in keep}, acquisition, fs_hz)
    logged = add_logging_noise(filtered, scenario["noise"])
    logged["fs_hz"] = np.asarray(fs_hz)
    exc = dict(res.meta["excitation"])
    exc["seed"] = scenario["seed"]          # base seed (x; y uses seed + 7919 when axis is both)
    meta = {
        "kind": "rig",
        "source": "python -m ssamb rig (simulated rig)",
        "excitation": exc,
        "start": scenario["start"],
        "duration_s": float(len(logged["t"]) / float(logged["fs_hz"])),
        "fs_hz": float(logged["fs_hz"]),
        "settle_s": float(res.meta["settle_s"]),
        "config_hash": scenario["nominal_config_hash"],
        "versions": versions(),
    }
    if acquisition:
        meta["acquisition"] = dict(acquisition)
    if scenario.get("description"):
        meta["description"] = str(scenario["description"])
    return logged, meta


def run_scenario(scenario_path: str | Path, out_path: str | Path, progress: bool = True, force: bool = False) -> None:
    """Simulate the rig described by a scenario file and write its data (atomically).

    Parameters
    ----------
    scenario_path : path
        Scenario YAML (docs/formats.md, "Scenario file").
    out_path : path
        Output ``.npz`` in the measured-data format (a ``.json`` sidecar with ``meta`` is
        written beside it).
    progress : bool
        Show the simulator's progress bar.
    force : bool
        Overwrite an existing output (or its sidecar); without, an existing one is an error.

    Raises
    ------
    ScenarioError
        Invalid scenario (nothing is written).
    ssamb.errors.InputError
        The output cannot go where ``out_path`` says (checked before the scenario is read).

    Examples
    --------
    >>> from ssamb.rig import run_scenario
    >>> run_scenario("resources/scenarios/rig_demo.yaml", "rig.npz")   # as python -m ssamb rig
    """
    from .io import check_output_file

    out = Path(out_path)
    if out.suffix != ".npz":
        raise ScenarioError(f"--out {out}: must end in .npz")
    check_output_file(out, force=force)
    sc = load_scenario(scenario_path)
    try:
        arrays, meta = rig_data(sc, progress=progress)
    except ScenarioError:
        raise
    except InputError as exc:          # the simulator's (no equilibrium, memory): name the scenario
        raise ScenarioError(f"{scenario_path}: {exc}") from None
    if sc.get("dtype", "float64") == "float32":
        arrays = {k: (v.astype(np.float32) if k not in ("t", "fs_hz") else v) for k, v in arrays.items()}
    save_measured_compressed(out, arrays, meta)


def save_measured_compressed(path: str | Path, arrays: Mapping[str, Any], meta: Mapping[str, Any]) -> None:
    """Like :func:`ssamb.io.save_measured` (validated first, atomic, JSON sidecar), compressed."""
    from .io import save_measured

    save_measured(path, arrays, meta, compress=True)


# -- the randomized suite's draws (bench/closeloop_suite.py, tests) ---------------------------------
#: experiment kinds a rig runs, as the randomized close-the-loop suite draws them
SUITE_KINDS = ("multisine", "pulses", "sweep", "rest")
#: the library effects the suite draws
SUITE_EFFECTS = ("sensor_delay", "unbalance", "static_load", "sensor_gain", "amplifier_deadtime", "cross_coupling")
#: logging noise of the suite's rigs (the logger's own ADC)
SUITE_NOISE = {"position_m": 3.0e-8, "current_a": 3.0e-4}
#: the calibratable parameters and how far a rig's may lie from the model's (uniform; relative, the
#: calibration offset absolute in m)
SUITE_PERTURB = {"table1.mass_kg": 0.05, "table1.airgap_m": 0.05, "table1.i_bias_a": 0.05, "table1.coil_turns": 0.05,
                 "table1.r_coil_ohm": 0.05, "magnetics.iron_conductivity_s_per_m": 0.05, "table1.mu_r": 0.05,
                 "table1.v_supply_v": 0.05, "sensors.x_bandwidth_hz": 0.05,
                 "selfsensing.calibration_gain_error": 0.05, "selfsensing.calibration_offset_error_m": 5.0e-6}


def draw_experiment(kind: str, rng: np.random.Generator, duration_s: tuple = (0.6, 1.0)) -> dict:
    """An experiment of ``kind`` as a rig might run it: ``{experiment, duration_s}`` for a
    scenario file (``duration_s`` None when the excitation sets it).

    * ``multisine``: a random-phase position multisine, lines every 5 or 10 Hz from 5-20 Hz up to
      50-250 Hz, 10-60 um peak, on x, y or both, whole periods filling ``duration_s``;
    * ``pulses``: the identification's rectangular current pulses before the amplifiers,
      0.1-0.4 A, 0.2 ms to 2-6 ms wide, on x, y or both;
    * ``sweep``: a linear position sweep, 15-50 um, from 5-15 Hz to 50-150 Hz over the record;
    * ``rest``: levitation without excitation (the loop's response to its own noise).
    """
    lo, hi = duration_s
    T = float(rng.uniform(lo, hi))
    axis = str(rng.choice(["x", "y", "both"]))
    seed = int(rng.integers(1, 100_000))
    if kind == "multisine":
        res = float(rng.choice([5.0, 10.0]))
        f_min = res * max(1, int(round(float(rng.uniform(5.0, 20.0)) / res)))
        f_max = res * int(round(float(rng.uniform(50.0, 250.0)) / res))
        periods = max(4, int(round(T * res)))
        return {"experiment": {"kind": "multisine", "point": "position", "axis": axis,
                               "amplitude_m": float(rng.uniform(10e-6, 60e-6)), "f_min_hz": f_min, "f_max_hz": f_max,
                               "f_resolution_hz": res, "periods": periods, "seed": seed}, "duration_s": None}
    if kind == "pulses":
        return {"experiment": {"kind": "pulses", "point": "current", "axis": axis,
                               "amplitude_a": float(rng.uniform(0.1, 0.4)), "min_width_s": 2.0e-4,
                               "max_width_s": float(rng.uniform(2e-3, 6e-3)), "seed": seed}, "duration_s": T}
    if kind == "sweep":
        return {"experiment": {"kind": "sweep", "point": "position", "axis": axis,
                               "amplitude_m": float(rng.uniform(15e-6, 50e-6)),
                               "f_start_hz": float(rng.uniform(5.0, 15.0)),
                               "f_stop_hz": float(rng.uniform(50.0, 150.0)),
                               "sweep_duration_s": T, "law": "linear"}, "duration_s": T}
    if kind == "rest":
        return {"experiment": {"kind": "none", "seed": seed}, "duration_s": T}
    raise ValueError(f"experiment kind '{kind}': unknown (known: {', '.join(SUITE_KINDS)})")


def draw_effect(effect: str, rng: np.random.Generator) -> dict:
    """One library effect with parameters from the ranges a rig may have."""
    if effect == "sensor_delay":
        return {"name": effect, "axis": str(rng.choice(["x", "y", "both"])),
                "delay_s": float(rng.uniform(5e-6, 100e-6))}
    if effect == "unbalance":
        f = float(rng.uniform(10.0, 200.0))
        return {"name": effect, "speed_hz": f, "mass_ecc_kgm": float(rng.uniform(0.5, 10.0)) / (2 * math.pi * f) ** 2,
                "phase_rad": float(rng.uniform(0, 2 * math.pi))}
    if effect == "static_load":
        f, a = float(rng.uniform(1.0, 20.0)), float(rng.uniform(0, 2 * math.pi))
        return {"name": effect, "fx_n": f * math.cos(a), "fy_n": f * math.sin(a)}
    if effect == "sensor_gain":
        g = float(rng.uniform(0.02, 0.2)) * float(rng.choice([-1.0, 1.0]))
        return {"name": effect, "axis": str(rng.choice(["x", "y", "both"])), "gain": 1.0 + g}
    if effect == "amplifier_deadtime":
        return {"name": effect, "deadtime_s": float(rng.uniform(0.2e-6, 2e-6))}
    if effect == "cross_coupling":
        return {"name": effect, "coefficient": float(rng.uniform(0.02, 0.2))}
    raise ValueError(f"effect '{effect}': unknown (known: {', '.join(SUITE_EFFECTS)})")


def draw_perturbation(rng: np.random.Generator, cfg: Mapping, widths: Mapping = SUITE_PERTURB) -> tuple[dict, dict]:
    """Every calibratable parameter off by a uniform draw within ``widths``: ``(overrides, changes)``
    (changes relative to the nominal value, absolute where it is 0)."""
    from .config import get

    ov, delta = {}, {}
    for key, width in widths.items():
        nominal = float(get(cfg, key))
        d = float(rng.uniform(-width, width))
        delta[key] = d
        ov[key] = nominal * (1 + d) if nominal != 0 else nominal + d
    return ov, delta


def effective_truth(scenario: Mapping, delta: Mapping, y_gain: float = 1.0) -> dict:
    """The rig's parameters as the model can see them (changes as in :func:`draw_perturbation`).

    The self-sensing calibration gain and offset errors act on top of a clamped calibration
    procedure that makes the DCM map exact at its positions for whatever physics it runs on; the
    model's own procedure is noise-free. So the errors the model must find are the rig's
    procedure's own (its noise, at its physics and with its effects: a cross coupling or a dead
    time changes what the clamped calibration reads) on top of the scenario's: the rig's
    calibration against a noise-free one at the same physics and effects. A y sensor gain
    ``G`` scales the calibrated estimate, :math:`y_{ss} = G (g y_{raw} + o)`: it *is* a
    calibration error, of gain :math:`G g` and offset :math:`G o` (``y_gain``: the part of it
    the analysis did not name as an effect).
    """
    from .sim import simulate

    rig_cfg, eff = scenario["cfg"], scenario["effects"]
    rig_cal = simulate(rig_cfg, duration_s=0.005, excitation=scenario["excitation"], start=scenario["start"],
                       seed=scenario["seed"], effects=eff, progress=False).meta["selfsensing_calibration"]
    model_cal = simulate(rig_cfg, arrays={"r_y": np.zeros(400)}, calibration_noise=False, effects=eff,
                         progress=False).meta["selfsensing_calibration"]
    g, o = "selfsensing.calibration_gain_error", "selfsensing.calibration_offset_error_m"
    out = dict(delta)
    out[g] = y_gain * rig_cal["gain"] * (1 + delta.get(g, 0.0)) / model_cal["gain"] - 1
    out[o] = y_gain * (rig_cal["offset_m"] + delta.get(o, 0.0)) - model_cal["offset_m"]
    return out
