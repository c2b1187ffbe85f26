"""Configuration: load ``config.yaml``, apply overrides, validate.

The configuration is a nested dictionary (as Snakemake sees it). :func:`load_config` reads a
YAML file, applies ``KEY=VALUE`` overrides with dotted keys, and validates the result with
:func:`validate_config`: first against the JSON Schema ``config.schema.yaml``, then against
cross-key physical rules that a schema cannot express. Every violation raises
:class:`ConfigError` whose message names the key and the rule broken.

Which file: an explicit path, else ``config.yaml`` in the working directory, else the default
configuration shipped inside the package (:func:`find_config`). The default configuration and
the schema are package data (``ssamb/data``, read with :mod:`importlib.resources`), so an
installed ssamb runs anywhere. In the repository they are symbolic links to the top-level
``config.yaml`` and ``workflow/schemas/config.schema.yaml``, the one copy a user edits and the
workflow reads; building a wheel or an archive stores their contents.
"""
from __future__ import annotations

import atexit
import contextlib
import copy
import functools
import hashlib
import json
import math
from importlib import resources
from pathlib import Path
from typing import Any, Iterable, Mapping

import yaml

from .errors import InputError, nonfinite_keys
from .io import jsonable

__all__ = [
    "ConfigError",
    "SCHEMA_PATH",
    "DEFAULT_CONFIG_PATH",
    "find_config",
    "load_config",
    "validate_config",
    "apply_overrides",
    "overridden",
    "config_hash",
    "get",
    "load_capacity_n",
    "PLAUSIBLE_RANGES",
]

_DATA_FILES = contextlib.ExitStack()
atexit.register(_DATA_FILES.close)


def _package_data(name: str) -> Path:
    """A file of ``ssamb/data`` as a path on disk (extracted for the process's lifetime when the
    package is imported from an archive)."""
    return Path(_DATA_FILES.enter_context(resources.as_file(resources.files("ssamb") / "data" / name)))


#: the JSON Schema every configuration is validated against (package data)
SCHEMA_PATH = _package_data("config.schema.yaml")
#: the default configuration: the paper's Table 1 and the modelling assumptions (package data)
DEFAULT_CONFIG_PATH = _package_data("config.yaml")


class ConfigError(InputError):
    """A configuration value breaks a rule; the message names the key and the rule."""


@functools.lru_cache(maxsize=1)
def _validator():
    import jsonschema

    with open(SCHEMA_PATH, encoding="utf-8") as fh:
        schema = yaml.load(fh, Loader=_YAML_LOADER)     # every process that checks a config reads it
    return jsonschema.validators.validator_for(schema)(schema)


def _path_str(path: Iterable[Any]) -> str:
    parts = [str(p) for p in path]
    return ".".join(parts) if parts else "<top level>"


def _schema_errors(cfg: Mapping) -> list[str]:
    msgs = []
    for err in sorted(_validator().iter_errors(cfg), key=lambda e: list(e.absolute_path)):
        key = _path_str(err.absolute_path)
        if err.validator == "required":
            # name the missing key itself, not its parent
            missing = err.message.split("'")[1] if "'" in err.message else err.message
            key = _path_str(list(err.absolute_path) + [missing])
            msgs.append(f"config key '{key}': missing (required)")
        elif err.validator == "additionalProperties":
            msgs.append(f"config key '{key}': {err.message} (unknown key: check the spelling)")
        else:
            msgs.append(f"config key '{key}': {err.message}{_number_hint(err.instance)}")
    return msgs


def _number_hint(value: Any) -> str:
    """A hint for a number YAML read as text: YAML 1.1 (PyYAML, Snakemake) reads ``1e30`` and
    ``3.e-4`` as strings; a float needs a dot and a signed exponent (``1.0e+30``)."""
    if not isinstance(value, str):
        return ""
    try:
        if not math.isfinite(float(value)):
            return ""
    except ValueError:
        return ""
    return f" (YAML reads {value} as text; write a number with a dot and a signed exponent, e.g. 1.0e+30)"


#: plausible ranges (SI) of the physical values a unit error moves by orders of magnitude: wide
#: enough for any radial AMB from a small pump's to a compressor's, narrow enough that a value
#: in mm, g, mA or kHz falls outside. Key -> (lowest, highest).
PLAUSIBLE_RANGES = {
    "table1.airgap_m": (2e-5, 5e-3),
    "table1.backup_clearance_m": (1e-5, 5e-3),
    "table1.mass_kg": (1e-3, 1e5),
    "table1.i_bias_a": (1e-3, 500.0),
    "table1.r_coil_ohm": (1e-4, 1e3),
    "table1.v_supply_v": (1.0, 1e4),
    "table1.f_pwm_hz": (100.0, 1e6),
    "table1.coil_turns": (1.0, 1e5),
    "table1.mu_r": (1.0, 1e6),
    "table1.axial_length_m": (1e-3, 2.0),
    "table1.r_journal_inner_m": (0.0, 1.0),
    "table1.r_journal_outer_m": (1e-3, 1.0),
    "table1.r_pole_m": (1e-3, 1.0),
    "table1.r_backiron_inner_m": (1e-3, 1.0),
    "table1.r_stator_outer_m": (1e-3, 2.0),
    "table1.pole_width_m": (1e-4, 1.0),
    "gravity_m_per_s2": (0.0, 100.0),
    "magnetics.b_knee_t": (0.1, 5.0),
    "magnetics.lamination_thickness_m": (1e-5, 5e-3),
    "magnetics.iron_conductivity_s_per_m": (0.0, 1e8),
    "amplifier.i_ref_max_a": (1e-3, 1e3),
    "controller.fs_hz": (100.0, 1e7),
    "controller.u_max_a": (1e-3, 500.0),
    "sensors.x_bandwidth_hz": (10.0, 1e7),
    "converters.position_adc_range_m": (1e-5, 0.1),
    "converters.current_adc_range_a": (1e-2, 1e4),
    "simulation.settle_s": (0.0, 10.0),
}

_MU0 = 4e-7 * 3.141592653589793


def load_capacity_n(cfg: Mapping) -> float:
    r"""An upper bound of the static force (N) one axis of the bearing can exert.

    The pulling magnet at its largest current :math:`i = i_0 + \min(u_{max}, i_0)` (the other at
    :math:`i_0 - \min(u_{max}, i_0) \ge 0` pulls against it, here neglected), its two poles in
    series across two airgaps :math:`g` with no iron reluctance and no saturation,
    :math:`B = \mu_0 N i / (2 g)`, each pole face :math:`A` = ``pole_width_m`` x
    ``axial_length_m`` pulling :math:`B^2 A / (2\mu_0)` at the pole half-angle :math:`\alpha`:

    .. math:: F_{max} = \frac{B^2 A}{\mu_0} \cos\alpha

    Iron, saturation and the other magnet only lower the force, so a load above this bound can
    never be carried (the simulator's equilibrium: 190 N against this bound's 198 N for the
    default config).
    """
    t1, geo = cfg["table1"], cfg["geometry"]
    n_turns = float(t1["coil_turns"]) * float(geo["coils_per_magnet"])
    i_max = float(t1["i_bias_a"]) + min(float(cfg["controller"]["u_max_a"]), float(t1["i_bias_a"]))
    b = _MU0 * n_turns * i_max / (2.0 * float(t1["airgap_m"]))
    area = float(t1["pole_width_m"]) * float(t1["axial_length_m"])
    return b * b * area / _MU0 * math.cos(math.radians(float(geo["pole_half_angle_deg"])))


def _unit_of_key(key: str) -> str:
    leaf = key.rsplit(".", 1)[-1]
    for suffix, unit in (("_m_per_s2", "m/s^2"), ("_s_per_m", "S/m"), ("_ohm", "ohm"), ("_kg", "kg"),
                         ("_hz", "Hz"), ("_m", "m"), ("_a", "A"), ("_v", "V"), ("_t", "T"), ("_s", "s")):
        if leaf.endswith(suffix):
            return f" {unit}"
    return ""


def _plausibility_errors(cfg: Mapping) -> list[str]:
    """Values no radial AMB has (:data:`PLAUSIBLE_RANGES`) and loads this bearing cannot carry:
    a unit error named by its key before anything is simulated."""
    msgs = []
    for key, (lo, hi) in PLAUSIBLE_RANGES.items():
        try:
            v = get(cfg, key)
        except ConfigError:
            continue
        if not lo <= v <= hi:
            msgs.append(f"config key '{key}': {v:g}{_unit_of_key(key)} lies outside the plausible range "
                        f"[{lo:g}, {hi:g}]{_unit_of_key(key)} of a radial AMB (a unit off by a factor 1000?)")
    if msgs:
        return msgs
    t1 = cfg["table1"]
    weight = float(cfg["weight_share"]) * float(t1["mass_kg"]) * float(cfg["gravity_m_per_s2"])
    cap = load_capacity_n(cfg)
    if weight > cap:
        msgs.append(f"config key 'table1.mass_kg': the bearing's share of the weight, weight_share x mass_kg x "
                    f"gravity_m_per_s2 = {weight:.4g} N, exceeds the most its magnets can pull, {cap:.4g} N (an upper "
                    "bound from table1.coil_turns x geometry.coils_per_magnet turns at table1.i_bias_a + "
                    "controller.u_max_a across table1.airgap_m): no levitated equilibrium")
    i_drive = float(t1["v_supply_v"]) / float(t1["r_coil_ohm"])
    if i_drive < float(t1["i_bias_a"]):
        msgs.append(f"config key 'table1.r_coil_ohm': {t1['r_coil_ohm']:g} ohm with table1.v_supply_v = "
                    f"{t1['v_supply_v']:g} V drives at most {i_drive:.3g} A, less than the bias table1.i_bias_a = "
                    f"{t1['i_bias_a']:g} A (resistance in milliohm?)")
    kp_min = 0.1 * float(t1["i_bias_a"]) / float(t1["airgap_m"])
    if float(t1["pid_kp_a_per_m"]) < kp_min:
        msgs.append(f"config key 'table1.pid_kp_a_per_m': {t1['pid_kp_a_per_m']:g} A/m is below a tenth of "
                    f"table1.i_bias_a / table1.airgap_m = {10 * kp_min:.4g} A/m, the least a PD needs to overcome "
                    "the magnets' negative stiffness (gain in A/mm?)")
    airgap = float(t1["airgap_m"])
    i_lim = float(cfg["amplifier"]["i_ref_max_a"])
    for name, exp in cfg["experiments"].items():
        exc = exp["excitation"]
        amp_m, amp_a = exc.get("amplitude_m"), exc.get("amplitude_a")
        if isinstance(amp_m, (int, float)) and not isinstance(amp_m, bool) and amp_m > airgap:
            msgs.append(f"config key 'experiments.{name}.excitation.amplitude_m': {amp_m:g} m exceeds the airgap "
                        f"table1.airgap_m = {airgap:g} m (amplitude in mm or um?)")
        if isinstance(amp_a, (int, float)) and not isinstance(amp_a, bool) and amp_a > i_lim:
            msgs.append(f"config key 'experiments.{name}.excitation.amplitude_a': {amp_a:g} A exceeds the amplifier's "
                        f"current clamp amplifier.i_ref_max_a = {i_lim:g} A (amplitude in mA?)")
    return msgs


def _physical_errors(cfg: Mapping) -> list[str]:
    msgs = _plausibility_errors(cfg)
    if msgs:
        return msgs
    t1 = cfg["table1"]
    if t1["backup_clearance_m"] >= t1["airgap_m"]:
        msgs.append(
            "config key 'table1.backup_clearance_m': must be smaller than table1.airgap_m "
            f"(got {t1['backup_clearance_m']} >= {t1['airgap_m']}); otherwise the rotor touches "
            "the stator before the backup bearing"
        )
    fs = cfg["controller"]["fs_hz"]
    fpwm = t1["f_pwm_hz"]
    ratio = fs / fpwm
    if abs(ratio - round(ratio)) < 1e-6 and round(ratio) >= 1:
        msgs.append(
            f"config key 'controller.fs_hz': {fs} Hz is an integer multiple ({round(ratio)}x) of "
            f"table1.f_pwm_hz = {fpwm} Hz; DCM self-sensing would sample the ripple at fixed "
            "phases and consistently miss its peak (paper section 3)"
        )
    if fs <= 2 * fpwm:
        msgs.append(
            f"config key 'controller.fs_hz': must exceed twice table1.f_pwm_hz ({2 * fpwm} Hz) so "
            "that the ripple peak can be detected (paper section 3)"
        )
    radii = ["r_journal_inner_m", "r_journal_outer_m", "r_pole_m", "r_backiron_inner_m", "r_stator_outer_m"]
    for a, b in zip(radii, radii[1:]):
        if not t1[a] < t1[b]:
            msgs.append(f"config key 'table1.{b}': must be larger than table1.{a} (got {t1[b]} <= {t1[a]})")
    if t1["r_pole_m"] - t1["r_journal_outer_m"] <= 0:
        pass  # covered above
    mag = cfg["magnetics"]
    amp = cfg["amplifier"]
    if amp["duty_min"] >= amp["duty_max"]:
        msgs.append("config key 'amplifier.duty_min': must be smaller than amplifier.duty_max")
    ss = cfg["selfsensing"]
    if ss["lowpass_hz"] >= fs / 2:
        msgs.append(f"config key 'selfsensing.lowpass_hz': must be below the Nyquist frequency {fs / 2} Hz")
    if cfg["controller"]["derivative_filter_hz"] >= fs / 2:
        msgs.append(f"config key 'controller.derivative_filter_hz': must be below the Nyquist frequency {fs / 2} Hz")
    if ss["calibrate"] and len(set(ss["calibration_positions_m"])) < 2:
        msgs.append("config key 'selfsensing.calibration_positions_m': needs two distinct positions")
    for p in ss["calibration_positions_m"]:
        if abs(p) >= t1["backup_clearance_m"]:
            msgs.append(
                f"config key 'selfsensing.calibration_positions_m': {p} m lies outside the backup "
                f"bearing clearance {t1['backup_clearance_m']} m"
            )
    for name, exp in cfg["experiments"].items():
        exc = exp["excitation"]
        if exc["kind"] != "none" and "point" not in exc:
            msgs.append(f"config key 'experiments.{name}.excitation.point': missing (required for kind "
                        f"'{exc['kind']}')")
        if exp["duration_s"] is None and exc["kind"] != "multisine":
            msgs.append(f"config key 'experiments.{name}.duration_s': null is only allowed for multisine excitation")
    del mag
    exps = cfg["experiments"]
    refs = []
    if "identification" in cfg:
        idc = cfg["identification"]
        refs += [("identification.estimation", idc["estimation"]), ("identification.validation", idc["validation"])]
        for sub in ("plant", "amplifier", "selfsensing"):
            if idc[sub]["order"] >= idc["ss_f"]:
                msgs.append(f"config key 'identification.{sub}.order': {idc[sub]['order']} must be below "
                            f"identification.ss_f = {idc['ss_f']} (SIPPY's future horizon)")
        if max(idc["order_scan"]["orders"], default=0) >= idc["ss_f"]:
            msgs.append("config key 'identification.order_scan.orders': every order must be below identification.ss_f")
    if "assembly" in cfg:
        refs.append(("assembly.fig4", cfg["assembly"]["fig4"]))
    if "uncertainty" in cfg:
        refs.append(("uncertainty.experiment", cfg["uncertainty"]["experiment"]))
        e = exps.get(cfg["uncertainty"]["experiment"])
        if e is not None and e["excitation"]["kind"] != "multisine":
            msgs.append("config key 'uncertainty.experiment': must name a multisine experiment (the ETFE is read on "
                        "its lines)")
    if "mu" in cfg and cfg["mu"]["f_min_hz"] >= cfg["mu"]["f_max_hz"]:
        msgs.append("config key 'mu.f_min_hz': must be below mu.f_max_hz")
    if "validation" in cfg:
        if "sweep" not in exps:
            msgs.append("config key 'experiments.sweep': missing (the validation stage needs the sweep experiment)")
        elif exps["sweep"]["excitation"]["kind"] != "sweep":
            msgs.append("config key 'experiments.sweep.excitation.kind': must be 'sweep'")
    for name, spec in ((cfg.get("study") or {}).get("assumptions") or {}).items():
        plain = [v for v in spec["values"] if not isinstance(v, Mapping)]
        if plain and "key" not in spec:
            msgs.append(f"config key 'study.assumptions.{name}.key': missing (its values are plain)")
        elif plain:
            try:
                get(cfg, spec["key"])
            except ConfigError:
                msgs.append(f"config key 'study.assumptions.{name}.key': '{spec['key']}' is not a key of the config")
    for key, name in refs:
        if name not in exps:
            msgs.append(f"config key '{key}': experiment '{name}' is not defined in 'experiments'")
    return msgs


def _excitation_errors(cfg: Mapping) -> list[str]:
    """Each experiment's excitation built once (cheap): names the experiment and the key."""
    from .signals import make_excitation

    msgs = []
    for name, exp in cfg["experiments"].items():
        try:
            make_excitation(exp["excitation"], float(cfg["controller"]["fs_hz"]), exp["duration_s"], cfg["seed"])
        except ValueError as exc:
            text = str(exc)
            if text.startswith("duration_s: "):
                msgs.append(f"config key 'experiments.{name}.duration_s': {text[len('duration_s: '):]}")
            else:
                msgs.append(f"config key 'experiments.{name}.excitation': {text}")
    return msgs


def validate_config(cfg: Mapping) -> None:
    """Validate a configuration dictionary; raise :class:`ConfigError` listing every violation.

    Three layers: no NaN or infinite number anywhere (:func:`ssamb.errors.nonfinite_keys`;
    JSON Schema's ``minimum`` lets NaN through), the schema
    (``workflow/schemas/config.schema.yaml``), then the cross-key physical rules and the
    excitation of every experiment (:func:`ssamb.signals.make_excitation`).

    Parameters
    ----------
    cfg : mapping
        The configuration (as loaded from ``config.yaml``).

    Raises
    ------
    ConfigError
        With one line per violation, each naming the dotted key and the rule it breaks.
    """
    bad = dict(nonfinite_keys(cfg))
    msgs = [f"config key '{k}': must be a finite number (got {v!r})" for k, v in bad.items()]
    msgs += [m for m in _schema_errors(cfg) if m.split("'")[1] not in bad]
    if not msgs:
        msgs = _physical_errors(cfg) or _excitation_errors(cfg)
    if msgs:
        raise ConfigError("; ".join(msgs))


def _parse_value(text: str) -> Any:
    """An override's value as YAML reads it, except that a number YAML 1.1 reads as text
    (``1e30``, ``5e-4``: no dot or no exponent sign) is a number, as a user typing it means."""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if isinstance(value, str):
        try:
            return float(value)       # nan and inf too: the finite-number check then names the key
        except ValueError:
            pass
    return value


def apply_overrides(cfg: Mapping, overrides: Iterable[str] | Mapping[str, Any] | None) -> dict:
    """Return a copy of ``cfg`` with dotted-key overrides applied.

    ``overrides`` is either an iterable of ``"a.b.c=VALUE"`` strings (VALUE parsed as YAML) or a
    mapping of dotted keys to values. An override of a key that does not exist is an error,
    so that a typo cannot silently leave the configuration unchanged.
    """
    out = copy.deepcopy(dict(cfg))
    if not overrides:
        return out
    items = overrides.items() if isinstance(overrides, Mapping) else (_split_override(s) for s in overrides)
    return _set_keys(out, items, copy_path=False)


def overridden(cfg: Mapping, overrides: Mapping[str, Any]) -> dict:
    """``cfg`` with dotted-key overrides applied, sharing every section they do not reach.

    The same configuration as :func:`apply_overrides` (and the same error for a key that does
    not exist), made by copying only the mappings on the overridden keys' paths: for a caller
    that reads it and never writes it (a replay's configuration per parameter set; a deep copy
    of the whole configuration costs more than a short replay's set-up).
    """
    return _set_keys(dict(cfg), overrides.items(), copy_path=True)


def _set_keys(out: dict, items: Iterable[tuple[str, Any]], copy_path: bool) -> dict:
    """Set every dotted key of ``items`` in ``out`` (each must exist); with ``copy_path`` the
    mappings on the way are copied first (once each), so that ``out`` shares none it changes."""
    copied = {id(out)}
    for key, value in items:
        parts = key.split(".")
        node = out
        for i, part in enumerate(parts[:-1]):
            if not isinstance(node, dict) or part not in node:
                raise ConfigError(f"config key '{'.'.join(parts[: i + 1])}': does not exist (override '{key}')")
            child = node[part]
            if copy_path and isinstance(child, dict) and id(child) not in copied:
                child = dict(child)
                node[part] = child
                copied.add(id(child))
            node = child
        if not isinstance(node, dict) or parts[-1] not in node:
            raise ConfigError(f"config key '{key}': does not exist (override '{key}')")
        node[parts[-1]] = value
    return out


def _split_override(text: str) -> tuple[str, Any]:
    if "=" not in text:
        raise ConfigError(f"override '{text}': expected KEY=VALUE")
    key, value = text.split("=", 1)
    return key.strip(), _parse_value(value.strip())


#: libyaml's safe loader when PyYAML was built with it (same documents, ~10x faster)
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _duplicate_key(node, path: tuple = (), seen_nodes: set | None = None) -> tuple[str, int, int] | None:
    """The first key that appears twice in one mapping of a composed YAML document, as
    ``(dotted key, first line, second line)``; None when every mapping's keys are distinct.

    YAML itself leaves a repeated key to the reader, and PyYAML keeps the last value silently:
    a value written twice in a config (one of them forgotten) would change the result unnoticed.
    """
    seen_nodes = set() if seen_nodes is None else seen_nodes
    if id(node) in seen_nodes:          # an alias: walked where it was defined
        return None
    seen_nodes.add(id(node))
    if isinstance(node, yaml.MappingNode):
        lines: dict = {}
        for key, value in node.value:
            name = str(key.value) if isinstance(key, yaml.ScalarNode) else "?"
            if isinstance(key, yaml.ScalarNode) and name != "<<":
                if name in lines:
                    return ".".join(path + (name,)), lines[name], key.start_mark.line + 1
                lines[name] = key.start_mark.line + 1
            found = _duplicate_key(value, path + (name,), seen_nodes)
            if found:
                return found
    elif isinstance(node, yaml.SequenceNode):
        for i, value in enumerate(node.value):
            head = path[:-1] + (f"{path[-1]}[{i}]",) if path else (f"[{i}]",)
            found = _duplicate_key(value, head, seen_nodes)
            if found:
                return found
    return None


def read_yaml_mapping(path: Path, label: str, error: type = ValueError) -> dict:
    """The mapping in a YAML file; ``error(f"{label}: ...")`` when the file is missing, is a
    folder, cannot be read, is not UTF-8 text, is not valid YAML, repeats a key in a mapping
    (named, with both lines) or does not hold a mapping at its top level."""
    path = Path(path)
    if not path.exists():
        raise error(f"{label}: not found")
    if path.is_dir():
        raise error(f"{label}: is a folder, not a YAML file")
    try:
        with open(path, encoding="utf-8") as fh:
            loader = _YAML_LOADER(fh)
            try:
                node = loader.get_single_node()
                dup = _duplicate_key(node) if node is not None else None
                data = loader.construct_document(node) if node is not None else None
            finally:
                loader.dispose()
    except yaml.YAMLError as exc:
        raise error(f"{label}: not valid YAML ({' '.join(str(exc).split())})") from None
    except UnicodeDecodeError:
        raise error(f"{label}: not a UTF-8 text (YAML) file") from None
    except OSError as exc:
        raise error(f"{label}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    if dup is not None:
        raise error(f"{label}: key '{dup[0]}' appears twice (lines {dup[1]} and {dup[2]}); a YAML reader "
                    "would keep the last value silently")
    if not isinstance(data, dict):
        raise error(f"{label}: top level must be a mapping")
    return data


def find_config(path: str | Path | None = None) -> Path:
    """The configuration file to use.

    Parameters
    ----------
    path : path, optional
        A configuration file given explicitly (``--config``).

    Returns
    -------
    Path
        ``path`` when given; else ``config.yaml`` in the working directory when there is one
        (a user's own configuration, or the repository's when run from a checkout); else the
        default configuration shipped with ssamb (:data:`DEFAULT_CONFIG_PATH`).
    """
    if path is not None:
        return Path(path)
    local = Path("config.yaml")
    return local if local.is_file() else DEFAULT_CONFIG_PATH


def load_config(path: str | Path | None = None, overrides=None) -> dict:
    """Load, override and validate a configuration file.

    Parameters
    ----------
    path : path, optional
        The configuration file; without it, :func:`find_config` chooses (``./config.yaml``,
        else the default shipped with ssamb).
    overrides : iterable of str or mapping, optional
        ``KEY=VALUE`` strings or a mapping of dotted keys to values
        (:func:`apply_overrides`), applied before validation.

    Returns
    -------
    dict
        The validated configuration.

    Raises
    ------
    ConfigError
        The file is missing or not a YAML mapping, or a value breaks the schema or a cross-key
        rule; the message names the file and the key.

    Examples
    --------
    >>> from ssamb.config import load_config
    >>> cfg = load_config(overrides=["table1.i_bias_a=2.5"])
    >>> cfg["table1"]["i_bias_a"]
    2.5
    """
    path = find_config(path)
    cfg = read_yaml_mapping(path, f"config file '{path}'", ConfigError)
    try:
        cfg = apply_overrides(cfg, overrides)
        validate_config(cfg)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return cfg


def config_hash(obj: Any) -> str:
    """SHA-256 (first 16 hex digits) of a JSON-serialisable object, key order independent."""
    blob = json.dumps(obj, sort_keys=True, default=jsonable).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def get(cfg: Mapping, dotted: str) -> Any:
    """Return ``cfg['a']['b']`` for ``dotted == 'a.b'``; a missing key raises ConfigError."""
    node: Any = cfg
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            raise ConfigError(f"config key '{dotted}': missing")
        node = node[part]
    return node
