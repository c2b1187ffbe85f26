r"""Variants of the chain: named scenarios and the assumption study, as config overrides, and
the plan that shares every stage whose inputs do not change between variants.

Runs
----
A *run* is the whole chain for one configuration. The default run writes to ``results/``;
every other run to ``results/runs/<name>/`` (the run *prefix* ``runs/<name>/``). Runs are

* the named scenarios of config ``scenarios`` (``name -> {dotted key: value}``), e.g. ``paper``;
* the assumption study of config ``study`` (:func:`study_variants`): a ``study-baseline`` run
  with the study's common overrides, one run per assumption value (one at a time) and one per
  value pair of the listed assumption pairs;
* the noise ensembles of config ``ensemble`` (:func:`ensemble_runs`): realisation ``k`` of a
  chain (the default run or a named scenario) is the run ``<chain>.r<k>``, the chain with the
  master ``seed`` moved by ``k`` (another draw of the converter noise, the excitation phases
  and the calibration noise); realisation 0 is the chain itself;
* the ceiling runs (:func:`ceiling_runs`): ``ceiling.r<k>`` repeats the default run's
  experiments with only the converter noise drawn anew (``converters.seed_offset`` moved by
  ``k``): nonlinear against nonlinear, the fit no model can exceed.

Sharing
-------
Each stage of each run has a *key*: a hash of the config it reads and of the keys of the stage
outputs it reads (:class:`Plan`). Two runs whose keys agree for a stage share its output: the
stage is planned once, under the first run (in the order default, scenarios, study) that has
that key (its *owner*), and every other run reads the owner's file. So a variant that changes
only the sweep re-simulates the sweep and re-validates, nothing else.
"""
from __future__ import annotations

import hashlib
import json
import re
from typing import Any, Callable, Mapping

from .channels import SUBSYSTEMS
from .config import ConfigError, apply_overrides, get

__all__ = ["SIM_SECTIONS", "sim_config", "identification_config", "study_variants", "ensemble_runs", "ensemble_chains",
           "ceiling_runs", "realisation_name", "default_scenarios", "run_overrides", "run_configs", "Plan", "CHAIN",
           "run_prefix"]

#: config sections the nonlinear simulator depends on (all physics, no analysis settings)
SIM_SECTIONS = ("seed", "table1", "geometry", "gravity_m_per_s2", "weight_share", "magnetics", "amplifier",
                "controller", "selfsensing", "sensors", "converters", "simulation")

_NAME = re.compile(r"^[A-Za-z0-9_.=+-]+$")


def sim_config(cfg: Mapping, experiment: str | None = None) -> dict:
    """The physics part of ``cfg`` plus only the named experiment (or all experiments)."""
    out = {k: cfg[k] for k in SIM_SECTIONS if k in cfg}
    exps = cfg["experiments"]
    out["experiments"] = {experiment: exps[experiment]} if experiment is not None else dict(exps)
    return json.loads(json.dumps(out))  # a deep copy made of plain containers


def identification_config(cfg: Mapping, subsystem: str) -> dict:
    """The ``identification`` section as one subsystem's identification reads it: the shared
    keys and that subsystem's own entry, without the other subsystems' (so that a changed
    ``identification.<subsystem>.order`` reruns that subsystem's identification only)."""
    return {k: v for k, v in cfg["identification"].items() if k not in SUBSYSTEMS or k == subsystem}


def _label(value: Any) -> str:
    """A file-name-safe label of a study value."""
    text = json.dumps(value, sort_keys=True) if isinstance(value, (dict, list)) else str(value)
    return re.sub(r"[^A-Za-z0-9_.+-]", "", text.replace(" ", ""))[:40] or "value"


def _assumption_values(name: str, spec: Mapping) -> dict[str, dict]:
    """``label -> overrides`` of one study assumption: each value is a scalar for ``key`` or a
    mapping ``{label, overrides}`` (several keys at once)."""
    out = {}
    for v in spec["values"]:
        if isinstance(v, Mapping):
            out[str(v["label"])] = dict(v["overrides"])
        else:
            out[_label(v)] = {spec["key"]: v}
    return out


def study_variants(config: Mapping) -> dict[str, dict]:
    """``run name -> overrides`` of the assumption study (config ``study``): ``study-baseline``
    (the study's common ``overrides`` only), ``study-<assumption>=<label>`` one at a time, and
    ``study-<a>=<la>+<b>=<lb>`` for every value pair of each listed pair of assumptions."""
    st = config.get("study") or {}
    base = dict(st.get("overrides") or {})
    values = {a: _assumption_values(a, spec) for a, spec in (st.get("assumptions") or {}).items()}
    out = {"study-baseline": base}
    for a, vals in values.items():
        for lab, ov in vals.items():
            out[f"study-{a}={lab}"] = {**base, **ov}
    for a, b in st.get("pairs") or []:
        for la, oa in values[a].items():
            for lb, ob in values[b].items():
                out[f"study-{a}={la}+{b}={lb}"] = {**base, **oa, **ob}
    return out


#: name of the default run among the chains of config ``ensemble.runs``
DEFAULT_CHAIN = "default"


def realisation_name(chain: str, k: int) -> str:
    """Run name of realisation ``k`` of a chain (``default`` or a scenario): ``<chain>.r<k>``."""
    return f"{chain}.r{int(k)}"


def ensemble_chains(config: Mapping) -> list[str]:
    """The chains of config ``ensemble.runs`` (``default`` and scenario names), checked."""
    ens = config.get("ensemble") or {}
    chains = [str(c) for c in ens.get("runs") or []]
    scen = config.get("scenarios") or {}
    if DEFAULT_CHAIN in scen:
        raise ConfigError(f"scenario name '{DEFAULT_CHAIN}': reserved for the default run (config ensemble.runs)")
    bad = [c for c in chains if c != DEFAULT_CHAIN and c not in scen]
    if bad:
        raise ConfigError(f"config key 'ensemble.runs': {bad} not '{DEFAULT_CHAIN}' nor a scenario of config "
                          "'scenarios'")
    return chains


def ensemble_runs(config: Mapping) -> dict[str, dict]:
    """``run name -> overrides`` of the noise ensembles (config ``ensemble``).

    For each chain of ``ensemble.runs`` and ``k = 0 .. realisations - 1`` the run
    :func:`realisation_name` ``(chain, k)``: the chain's own overrides and, for ``k > 0``, the
    ensemble's common ``overrides`` (evidence only realisation 0 needs to report) and
    ``seed = seed + k`` -- every random signal derives from the master seed, so this is an
    independent draw of the converter noise, the excitation phases and the calibration noise.
    Realisation 0 has exactly the chain's config, so every stage of it is the chain's own.
    """
    ens = config.get("ensemble") or {}
    K = int(ens.get("realisations", 0))
    common = dict(ens.get("overrides") or {})
    scen = config.get("scenarios") or {}
    out = {}
    for chain in ensemble_chains(config):
        own = {} if chain == DEFAULT_CHAIN else dict(scen[chain] or {})
        for k in range(K):
            out[realisation_name(chain, k)] = dict(own) if k == 0 else {**own, **common,
                                                                           "seed": int(config["seed"]) + k}
    return out


def ceiling_runs(config: Mapping) -> dict[str, dict]:
    """``run name -> overrides`` of the ceiling runs: ``ceiling.r<k>``, ``k = 1 .. realisations - 1``,
    the default run's experiments with ``converters.seed_offset`` moved by ``k`` (only the
    converter noise differs: the same excitation and rig, another run of it)."""
    K = int((config.get("ensemble") or {}).get("realisations", 0))
    off = int(config["converters"]["seed_offset"])
    return {realisation_name("ceiling", k): {"converters.seed_offset": off + k} for k in range(1, K)}


def default_scenarios(config: Mapping) -> list[str]:
    """The scenarios the default target runs: config ``default_scenarios`` (every scenario when
    the key is absent), each checked to be a scenario of config ``scenarios``."""
    scen = list(config.get("scenarios") or {})
    names = [str(n) for n in config.get("default_scenarios", scen)]
    bad = [n for n in names if n not in scen]
    if bad:
        raise ConfigError(f"config key 'default_scenarios': {bad} not a scenario of config 'scenarios'")
    return names


def run_overrides(config: Mapping, study: bool = True, ensemble: bool = True) -> dict[str, dict]:
    """``run name -> overrides`` of every run: ``""`` (default), the scenarios, the study, the
    noise ensembles and the ceiling runs."""
    runs = {"": {}}
    runs.update({str(k): dict(v or {}) for k, v in (config.get("scenarios") or {}).items()})
    if study:
        runs.update(study_variants(config))
    if ensemble:
        runs.update(ensemble_runs(config))
        runs.update(ceiling_runs(config))
    bad = [n for n in runs if n and not _NAME.match(n)]
    if bad:
        raise ConfigError(f"run names {bad}: use letters, digits and _.=+- only")
    return runs


def run_prefix(name: str) -> str:
    """The results sub-folder of a run: ``''`` for the default, ``'runs/<name>/'`` otherwise."""
    return f"runs/{name}/" if name else ""


def run_configs(config: Mapping, study: bool = True, ensemble: bool = True) -> dict[str, dict]:
    """``run prefix -> config`` of every run (each override must name an existing key)."""
    out = {}
    for name, ov in run_overrides(config, study, ensemble).items():
        try:
            out[run_prefix(name)] = apply_overrides(config, ov)
        except ConfigError as exc:
            raise ConfigError(f"run '{name or 'default'}': {exc}") from None
    return out


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


class Plan:
    """Stage keys and owners over the runs (module docstring, "Sharing").

    Parameters
    ----------
    runs : mapping
        ``run prefix -> config`` (:func:`run_configs`).
    chain : mapping
        ``stage -> f(cfg, **wildcards) -> (own, upstream)``: what the stage reads from the config
        (any JSON-able value) and the stage outputs it reads, as ``(stage, wildcards)`` pairs.
    """

    def __init__(self, runs: Mapping[str, Mapping], chain: Mapping[str, Callable] | None = None):
        self.runs = dict(runs)
        self.chain = dict(CHAIN if chain is None else chain)
        self._keys: dict = {}
        self._owners: dict = {}

    def key(self, stage: str, run: str, **wc) -> str:
        """Hash of the stage's own config and its inputs' keys in ``run``."""
        memo = (stage, run, tuple(sorted(wc.items())))
        if memo not in self._keys:
            own, upstream = self.chain[stage](self.runs[run], **wc)
            ups = [self.key(s, run, **w) for s, w in upstream]
            blob = _canonical([stage, sorted(wc.items()), own, ups]).encode()
            self._keys[memo] = hashlib.sha256(blob).hexdigest()[:16]
        return self._keys[memo]

    def owner(self, stage: str, run: str, **wc) -> str:
        """The first run (default, scenarios, study) with the same key: whose file ``run`` reads."""
        memo = (stage, run, tuple(sorted(wc.items())))
        if memo not in self._owners:
            k = self.key(stage, run, **wc)
            self._owners[memo] = next(r for r in self.runs if self.key(stage, r, **wc) == k)
        return self._owners[memo]


# ------------------------------------------------------------------ the chain's data flow
def _exp(cfg, dotted: str) -> str:
    return get(cfg, dotted)


def _pid(cfg) -> dict:
    return {"table1": cfg["table1"], "controller": cfg["controller"]}


def _identified(cfg) -> list:
    """The stage outputs that hold a run's three models: the identification's, or the selection's
    by the assembled loop (``identification.selection: loop``)."""
    if cfg["identification"].get("selection", "subsystem") == "loop":
        return [("select", {})]
    return [("identify", {"subsystem": s}) for s in SUBSYSTEMS]


def _mu_grid(cfg) -> dict:
    """What a mu job reads of the mu section: the grid (the list of cases selects jobs)."""
    return {k: v for k, v in cfg["mu"].items() if k != "cases"}


def _mu_subsystems(case: str) -> tuple:
    return SUBSYSTEMS if case == "all" else (case,)


#: stage -> (own config, upstream stage outputs) -- the arrows of the data flow
CHAIN: dict[str, Callable] = {
    "simulate": lambda cfg, experiment: (sim_config(cfg, experiment), []),
    "identify": lambda cfg, subsystem: (identification_config(cfg, subsystem), [
        ("simulate", {"experiment": _exp(cfg, "identification.estimation")}),
        ("simulate", {"experiment": _exp(cfg, "identification.validation")})]),
    "select": lambda cfg: ([cfg["identification"], _pid(cfg)], [("identify", {"subsystem": s}) for s in SUBSYSTEMS]
                           + [("simulate", {"experiment": _exp(cfg, "identification.validation")})]),
    "assemble": lambda cfg: ([cfg["assembly"], _pid(cfg)],
                             _identified(cfg) + [("simulate", {"experiment": _exp(cfg, "assembly.fig4")})]),
    "uncertainty": lambda cfg, subsystem: (cfg["uncertainty"], [
        ("assemble", {}), ("simulate", {"experiment": _exp(cfg, "uncertainty.experiment")})] + _identified(cfg)),
    "mu": lambda cfg, case: ([_mu_grid(cfg), _pid(cfg)], _identified(cfg) + [
        ("uncertainty", {"subsystem": s}) for s in _mu_subsystems(case)]),
    "baseline": lambda cfg: ([_mu_grid(cfg), _pid(cfg)], _identified(cfg)),
    "validate": lambda cfg: ([cfg["validation"], sim_config(cfg, "sweep")], _identified(cfg) + [
        ("simulate", {"experiment": "sweep"}), ("uncertainty", {"subsystem": cfg["validation"]["weight"]})]),
}
