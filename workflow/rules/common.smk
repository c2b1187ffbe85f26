# Helpers shared by the rule files. The config is validated here, at parse time, so that a bad
# value stops the workflow with the schema message before any job runs.
import copy

from ssamb.config import ConfigError, validate_config

try:
    validate_config(config)
    _missing = [k for k in ("identification", "assembly", "uncertainty", "mu", "validation", "closeloop")
                if k not in config]
    if _missing:
        raise ConfigError("; ".join(f"config key '{k}': missing (required by the workflow)" for k in _missing))
except ConfigError as _err:
    raise WorkflowError(f"config.yaml: {_err}") from None

#: config sections the nonlinear simulator depends on (all physics, no analysis settings)
SIM_SECTIONS = ["seed", "table1", "geometry", "gravity_m_per_s2", "weight_share", "magnetics", "amplifier",
                "controller", "selfsensing", "sensors", "converters", "simulation"]

#: experiments simulated by default (all that the config defines)
SIM_EXPERIMENTS = list(config["experiments"])


def sim_config(wildcards=None):
    """The physics part of the config plus only the experiment this job runs."""
    out = {k: copy.deepcopy(config[k]) for k in SIM_SECTIONS}
    exps = config["experiments"]
    if wildcards is not None and "experiment" in wildcards.keys():
        out["experiments"] = {wildcards.experiment: copy.deepcopy(exps[wildcards.experiment])}
    else:
        out["experiments"] = copy.deepcopy(exps)
    return out


def section(*keys):
    """Params helper: the named config sections (a dict), for rules that use whole sections."""
    return {k: copy.deepcopy(config[k]) for k in keys}
