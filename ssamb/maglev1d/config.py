"""The levitated ball's configuration: ``config.yaml`` (package data), user files, overrides.

A user's file may give any subset of the keys of the default configuration; the rest keep
their defaults. Every physical value must be a finite number within its range, and a key the
default lacks is an error: :class:`ssamb.config.ConfigError`, one line naming the file and the
dotted key. The ``closeloop`` section is this device's analysis settings; close the loop reads
and checks it (only its ``calibration`` keys are checked here: each must name a number of the
model's config, with a tolerance > 0).
"""
from __future__ import annotations

import copy
import functools
import math
from importlib import resources
from pathlib import Path
from typing import Mapping

import yaml

from ..config import ConfigError

__all__ = ["default_config", "load_config", "validate", "get"]

#: (lower, upper, inclusive lower) of each physical key; every other numeric key must be > 0
_RANGES = {
    "stops.top_m": (0.0, 0.05, True),
    "sensors.position_offset_m": (-0.01, 0.01, True),
    "sensors.position_curvature_per_m": (-30.0, 90.0, True),
    "amplifier.drop_v": (0.0, 10.0, True),
    "stops.restitution": (0.0, 1.0, True),
    "noise.position_m": (0.0, 1e-3, True),
    "noise.current_a": (0.0, 1.0, True),
    "noise.force_n": (0.0, 1.0, True),
    "replay.additive_quantisers": (0.0, 1.0, True),
    "levitation.settle_s": (0.0, 10.0, True),
}


@functools.lru_cache(maxsize=1)
def _default_text() -> str:
    return resources.files("ssamb.maglev1d").joinpath("config.yaml").read_text(encoding="utf-8")


def default_config() -> dict:
    """The nominal configuration (a fresh copy)."""
    return copy.deepcopy(_default_parsed())


@functools.lru_cache(maxsize=1)
def _default_parsed() -> dict:
    """The nominal configuration, parsed once (never handed out: :func:`default_config` copies it)."""
    return yaml.safe_load(_default_text())


def get(cfg: Mapping, key: str):
    node = cfg
    for part in key.split("."):
        node = node[part]
    return node


def _merge(base: dict, new: Mapping, where: str, prefix: str = "") -> None:
    for k, v in new.items():
        key = f"{prefix}{k}"
        if prefix == "closeloop.":
            base[k] = copy.deepcopy(v)           # the analysis settings: close the loop checks them
            continue
        if k not in base:
            raise ConfigError(f"{where}: key '{key}': unknown (known: {', '.join(base)})")
        if isinstance(base[k], dict):
            if not isinstance(v, Mapping):
                raise ConfigError(f"{where}: key '{key}': must be a mapping")
            _merge(base[k], v, where, f"{key}.")
        else:
            base[k] = v


def validate(cfg: Mapping, where: str = "maglev1d config") -> None:
    """Check every physical value; :class:`ConfigError` naming ``where`` and the dotted key."""
    for sec, body in cfg.items():
        if sec == "closeloop":
            continue
        for k, v in body.items():
            key = f"{sec}.{k}"
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"{where}: key '{key}': must be a finite number (got {v!r})")
            lo, hi, incl = _RANGES.get(key, (0.0, math.inf, False))
            if not ((v >= lo if incl else v > lo) and v <= hi):
                raise ConfigError(f"{where}: key '{key}': must be in {'[' if incl else '('}{lo:g}, {hi:g}] (got {v!r})")
    if cfg["stops"]["bottom_m"] <= cfg["stops"]["top_m"] + 2 * cfg["levitation"]["margin_m"]:
        raise ConfigError(f"{where}: key 'stops.bottom_m': must lie more than two levitation margins below stops.top_m")
    if cfg["amplifier"]["pwm_steps"] != int(cfg["amplifier"]["pwm_steps"]):
        raise ConfigError(f"{where}: key 'amplifier.pwm_steps': must be a whole number")
    if cfg["replay"]["substeps"] != int(cfg["replay"]["substeps"]) or cfg["replay"]["substeps"] < 2:
        raise ConfigError(f"{where}: key 'replay.substeps': must be a whole number >= 2")
    if cfg["replay"].get("additive_quantisers", 0) not in (0, 1):
        raise ConfigError(f"{where}: key 'replay.additive_quantisers': must be 0 or 1")
    cal = (cfg.get("closeloop") or {}).get("calibration") or {}
    if not isinstance(cal, Mapping):
        raise ConfigError(f"{where}: key 'closeloop.calibration': must be a mapping of dotted keys to tolerances")
    for key, tol in cal.items():
        try:
            val = get(cfg, key)
        except (KeyError, TypeError):
            raise ConfigError(f"{where}: key 'closeloop.calibration.{key}': not a key of the model's config") from None
        if isinstance(val, Mapping) or key.startswith("closeloop."):
            raise ConfigError(f"{where}: key 'closeloop.calibration.{key}': not a number of the model's config")
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not math.isfinite(tol) or tol <= 0:
            raise ConfigError(f"{where}: key 'closeloop.calibration.{key}': the tolerance must be a number > 0")


def load_config(path: str | Path | None = None, overrides: Mapping | None = None) -> dict:
    """The default configuration updated by the file ``path`` and ``overrides`` (dotted keys).

    Raises
    ------
    ssamb.config.ConfigError
        An unreadable file, an unknown key, a value out of range (named).
    """
    cfg = default_config()
    where = "maglev1d config"
    if path is not None:
        where = str(path)
        try:
            text = Path(path).read_text(encoding="utf-8")
            user = yaml.safe_load(text) or {}
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise ConfigError(f"{path}: cannot read a YAML configuration ({' '.join(str(exc).split())})") from None
        if not isinstance(user, Mapping):
            raise ConfigError(f"{path}: top level must be a mapping of sections")
        _merge(cfg, user, where)
    for key, v in (overrides or {}).items():
        parts = key.split(".")
        node = cfg
        for p in parts[:-1]:
            if not isinstance(node, dict) or p not in node:
                raise ConfigError(f"{where}: key '{key}': unknown")
            node = node[p]
        if parts[0] != "closeloop" and parts[-1] not in node:
            raise ConfigError(f"{where}: key '{key}': unknown")
        node[parts[-1]] = v
    validate(cfg, where)
    return cfg
