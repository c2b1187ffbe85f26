# Helpers shared by the rule files. The config is validated here, at parse time, so that a bad
# value stops the workflow with the schema message before any job runs.
#
# Runs (ssamb.scenarios): the default run writes to results/, every named scenario (config
# `scenarios`) and every variant of the assumption study (config `study`) to
# results/runs/<name>/. Every rule's paths carry the run prefix as the wildcard {run} ("" or
# "runs/<name>/"); a rule reads its config values from RUN_CONFIGS[wildcards.run], and every input
# points at the run that owns it (PLAN.owner), so a stage whose inputs do not change between
# runs is computed once.
import os
from pathlib import Path as _Path

from ssamb.channels import SUBSYSTEMS
from ssamb.config import ConfigError, read_yaml_mapping, validate_config
from ssamb.device import get_device
from ssamb.errors import InputError
from ssamb.stages import check_closeloop_settings
from ssamb.scenarios import (Plan, ceiling_runs, default_scenarios, ensemble_chains, identification_config,
                             realisation_name, run_configs, run_prefix, sim_config as _sim_config, study_variants)

def _patch_list_params_changes():
    """``snakemake --list-changes params`` lists, in Snakemake 9 (9.27.1 included), the last
    output file of every job whose params did *not* change: an unchanged ``ParamsChange`` ORed
    with another keeps the other's file (persistence.ParamsChange.__or__), and listing iterates
    the files without asking whether anything changed. List a job's files only when its params
    changed (what the option promises; a dry run's "Params have changed" agrees)."""
    from snakemake.persistence import ParamsChange

    if not getattr(ParamsChange, "_lists_changed_only", False):
        ParamsChange.__iter__ = lambda self: iter(self.files if self else ())
        ParamsChange._lists_changed_only = True


_patch_list_params_changes()


def canonical(obj):
    """``obj`` with the keys of every mapping in sorted order (lists keep theirs).

    Snakemake compares a rule's params by their text, in which a dict's key order shows; with
    the config canonical, reordering keys in config.yaml (no value changed) reruns nothing.
    """
    if isinstance(obj, dict):
        return {k: canonical(obj[k]) for k in sorted(obj, key=str)}
    if isinstance(obj, list):
        return [canonical(v) for v in obj]
    return obj


# Every rule's params derive from `config`: make it canonical in place, once, here.
_canonical = canonical(config)
config.clear()
config.update(_canonical)

#: the config files this invocation merged (the Snakefile's and every --configfile), for messages
CONFIG_FILES = list(dict.fromkeys(os.path.relpath(f) for f in workflow.configfiles)) or ["config.yaml"]


def _stop(message, where=" + ".join(CONFIG_FILES)):
    """Bad config: one line naming the file(s) and the key, exit status 2 before any job (as the
    command line does); a WorkflowError would exit 1 and add Snakemake's location lines."""
    import sys

    sys.stderr.write(f"{where + ': ' if where else ''}{' '.join(str(message).split())}\n")
    raise SystemExit(2)


# Snakemake's YAML reader keeps the last of a key written twice: read every config file again
# with ours, which names the file, the key and both lines
for _file in CONFIG_FILES:
    try:
        read_yaml_mapping(_Path(_file), _file, ConfigError)
    except ConfigError as _err:
        _stop(_err, where="")

try:
    validate_config(config)
    check_closeloop_settings(config)
    _missing = [k for k in ("identification", "assembly", "uncertainty", "mu", "validation", "closeloop")
                if k not in config]
    if _missing:
        raise ConfigError("; ".join(f"config key '{k}': missing (required by the workflow)" for k in _missing))
    for _name, _path in (config["closeloop"].get("datasets") or {}).items():
        if not _Path(_path).is_file():
            raise ConfigError(f"config key 'closeloop.datasets.{_name}': data file '{_path}' not found")
    for _rig, _spec in (config["closeloop"].get("rigs") or {}).items():
        for _part in ("fit", "hold"):
            for _name, _path in (_spec.get(_part) or {}).items():
                if not _Path(_path).is_file():
                    raise ConfigError(f"config key 'closeloop.rigs.{_rig}.{_part}.{_name}': data file '{_path}' not found")
        try:
            get_device(_spec.get("device")).load_config(_spec.get("config"))
        except InputError as _err:
            raise ConfigError(f"config key 'closeloop.rigs.{_rig}': {_err}") from None
    RUN_CONFIGS = run_configs(config)
    for _run, _cfg in RUN_CONFIGS.items():
        try:
            validate_config(_cfg)
        except ConfigError as _err:
            raise ConfigError(f"run '{_run.removeprefix('runs/').rstrip('/') or 'default'}': {_err}") from None

    #: run prefixes of the scenarios the default target runs
    SCENARIO_RUNS = [run_prefix(n) for n in default_scenarios(config)]
    #: chain -> [(run name, its summary.json), ...] of its realisations, realisation 0 first
    #: (the noise ensembles, config `ensemble`)
    ENSEMBLE_RUNS = {c: [(n, f"results/{run_prefix(n)}summary.json")
                         for n in (realisation_name(c, k) for k in range(int(config["ensemble"]["realisations"])))]
                     for c in ensemble_chains(config)} if config.get("ensemble") else {}
except ConfigError as _err:
    _stop(_err)

PLAN = Plan(RUN_CONFIGS)
STUDY_RUNS = [run_prefix(n) for n in study_variants(config)]
#: run prefixes of the ceiling runs (the default run's experiments, converter noise drawn anew)
CEILING_RUNS = [run_prefix(n) for n in ceiling_runs(config)]
#: experiments of the default run
SIM_EXPERIMENTS = list(config["experiments"])


wildcard_constraints:
    run="(runs/[A-Za-z0-9_.=+-]+/)?",
    experiment="[A-Za-z0-9_]+",
    subsystem="plant|amplifier|selfsensing",
    case="selfsensing|amplifier|plant|all",


def cfg_of(wc):
    """The config of the job's run."""
    return RUN_CONFIGS[wc.run]


def sim_config(wc):
    """Params: the physics of the job's run plus only its experiment."""
    return _sim_config(cfg_of(wc), wc.experiment if "experiment" in wc.keys() else None)


def section(*keys):
    """Params helper: the named config sections of the job's run."""
    return lambda wc: {k: cfg_of(wc)[k] for k in keys}


def out(stage, run, path, **wc):
    """results/<owner prefix><path>: the file ``run`` reads for ``stage`` (its owner's)."""
    return f"results/{PLAN.owner(stage, run, **wc)}{path}"


def sim_file(run, experiment):
    return out("simulate", run, f"sim/{experiment}.npz", experiment=experiment)


def model_files(run, suffix=""):
    """The three models of a run: identified per subsystem, or selected by the assembled loop
    (config identification.selection: loop); ``suffix='_paper'``: the other structures."""
    if not suffix and RUN_CONFIGS[run]["identification"].get("selection", "subsystem") == "loop":
        return [out("select", run, f"select/{s}.npz") for s in SUBSYSTEMS]
    return [out("identify", run, f"ident/{s}{suffix}.npz", subsystem=s) for s in SUBSYSTEMS]


def weight_file(run, subsystem):
    return out("uncertainty", run, f"uncertainty/{subsystem}_weight.npz", subsystem=subsystem)
