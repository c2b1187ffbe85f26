"""The chain is written twice, and this test holds the two together: the Snakemake rules (their
inputs and ``params:``) and the scenario planner's data flow (:data:`ssamb.scenarios.CHAIN`,
which decides which runs share a stage's file).

For every stage of the default run and of the paper's-way run:

* **inputs**: each file a job reads is made by a stage that the planner lists upstream of it,
  or by one of their ancestors (else two runs could share a file made from different inputs);
  and each stage the planner lists upstream is an ancestor of the job in the rules (else the
  planner keys on something the job never reads);
* **params**: changing any single value of the run's configuration that changes the job's
  ``params:`` also changes the planner's key (else a run would read another run's file made
  with other settings). Every leaf of the configuration is changed in turn.

The workflow is parsed in-process (no job runs), with the smoke configuration of the workflow
tests.
"""
from __future__ import annotations

import copy
import json

import pytest
from conftest import ROOT

from ssamb.scenarios import CHAIN, Plan

RUNS = ("", "runs/paper/")


@pytest.fixture(scope="module")
def workflow(tmp_path_factory):
    from snakemake.api import SnakemakeApi
    from snakemake.settings.types import ConfigSettings, OutputSettings, ResourceSettings

    import yaml

    wd = tmp_path_factory.mktemp("chain")
    smoke = wd / "smoke.yaml"
    cfg = yaml.safe_load((ROOT / "tests" / "data" / "smoke_config.yaml").read_text())
    cfg["closeloop"].pop("datasets", None)      # the record the smoke copy makes is not needed here
    cfg["closeloop"]["rigs"]["maglev1d"]["config"] = str(ROOT / "tests" / "data" / "maglev1d_smoke.yaml")
    smoke.write_text(yaml.safe_dump(cfg))
    with SnakemakeApi(OutputSettings()) as api:
        wf = api.workflow(resource_settings=ResourceSettings(cores=1),
                          config_settings=ConfigSettings(configfiles=[ROOT / "config.yaml", smoke]),
                          snakefile=ROOT / "Snakefile", workdir=ROOT)
        yield wf._workflow


def _jobs(g) -> list[tuple[str, str, dict]]:
    """``(stage, run, wildcards)`` of every planner stage in the default and paper's-way runs."""
    out = []
    for run in RUNS:
        if run not in g["RUN_CONFIGS"]:
            continue
        cfg = g["RUN_CONFIGS"][run]
        exps = list(cfg["experiments"]) if not run else sorted({
            cfg["identification"]["estimation"], cfg["identification"]["validation"], cfg["assembly"]["fig4"],
            cfg["uncertainty"]["experiment"], "sweep"})
        for stage in CHAIN:
            if stage == "select" and cfg["identification"].get("selection", "subsystem") != "loop":
                continue
            if stage == "simulate":
                out += [(stage, run, {"experiment": e}) for e in exps]
            elif stage in ("identify", "uncertainty"):
                out += [(stage, run, {"subsystem": s}) for s in g["SUBSYSTEMS"]]
            elif stage == "mu":
                out += [(stage, run, {"case": c}) for c in cfg["mu"]["cases"]]
            else:
                out.append((stage, run, {}))
    return out


def _wildcards(run: str, wc: dict):
    from snakemake.iocontainers import Wildcards

    return Wildcards(fromdict={"run": run, **wc})


def _params(rule, wcs) -> str:
    vals = {k: (v(wcs) if callable(v) else v) for k, v in rule.params._allitems()}
    return json.dumps(vals, sort_keys=True, default=str)


def _inputs(rule, wcs) -> list[str]:
    files = rule.expand_input(wcs)[0]
    return [str(f) for f in files]


def _producer(workflow, path: str) -> tuple[str, dict] | None:
    for rule in workflow.rules:
        if rule.name in CHAIN and rule.is_producer(path):
            wc = dict(rule.get_wildcards(path))
            return rule.name, {k: v for k, v in wc.items() if k != "run"}
    return None


def _key(stage, wc):
    return stage, tuple(sorted(wc.items()))


def _closure(cfg, stage, wc) -> set:
    """The planner's upstream stages of a job and all their ancestors."""
    seen, todo = set(), list(CHAIN[stage](cfg, **wc)[1])
    while todo:
        s, w = todo.pop()
        if _key(s, w) not in seen:
            seen.add(_key(s, w))
            todo += CHAIN[s](cfg, **w)[1]
    return seen


def test_the_rules_read_what_the_planner_keys_on(workflow):
    g = workflow.globals
    mismatches = []
    for stage, run, wc in _jobs(g):
        cfg = g["RUN_CONFIGS"][run]
        rule = workflow.get_rule(stage)
        planned = {_key(s, w) for s, w in CHAIN[stage](cfg, **wc)[1]}
        allowed = _closure(cfg, stage, wc)
        direct = set()
        for f in _inputs(rule, _wildcards(run, wc)):
            prod = _producer(workflow, f)
            if prod is not None:
                direct.add(_key(*prod))
        ancestors = set()
        for s, w in direct:
            ancestors |= {(s, w)} | _closure(cfg, s, dict(w))
        label = f"{stage} {dict(wc)} in run '{run or 'default'}'"
        for d in sorted(direct - allowed):
            mismatches.append(f"{label}: the rule reads {d[0]} {dict(d[1])}, which the planner does not key on")
        for p in sorted(planned - ancestors):
            mismatches.append(f"{label}: the planner keys on {p[0]} {dict(p[1])}, which the rule does not read")
    assert not mismatches, "\n".join(mismatches)


def _leaves(obj, path=()):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaves(v, path + (k,))
    else:
        yield path


def _mutated(value):
    if isinstance(value, bool):
        return not value
    if isinstance(value, (int, float)):
        return value * 1.37 + 1
    if isinstance(value, str):
        return value + "_changed"
    if isinstance(value, list):
        return value + value[-1:] if value else [1]
    return 1


def test_a_changed_value_in_params_changes_the_planners_key(workflow):
    g = workflow.globals
    jobs = _jobs(g)
    base_configs = g["RUN_CONFIGS"]
    rules = {stage: workflow.get_rule(stage) for stage in CHAIN}
    base_plan = Plan(base_configs)
    base = {(s, r, _key(s, wc)): (_params(rules[s], _wildcards(r, wc)), base_plan.key(s, r, **wc))
            for s, r, wc in jobs}
    mismatches, tried = set(), 0
    try:
        for run in RUNS:
            if run not in base_configs:
                continue
            for leaf in _leaves(base_configs[run]):
                cfg = copy.deepcopy(base_configs[run])
                node = cfg
                for k in leaf[:-1]:
                    node = node[k]
                node[leaf[-1]] = _mutated(node[leaf[-1]])
                g["RUN_CONFIGS"] = {**base_configs, run: cfg}
                plan = Plan(g["RUN_CONFIGS"])
                for s, r, wc in jobs:
                    if r != run:
                        continue
                    try:
                        params = _params(rules[s], _wildcards(r, wc))
                        key = plan.key(s, r, **wc)
                    except (KeyError, TypeError, ValueError, IndexError):
                        continue        # a value the chain cannot take at all
                    tried += 1
                    p0, k0 = base[(s, r, _key(s, wc))]
                    if params != p0 and key == k0:
                        mismatches.add(f"{s} {wc} in run '{r or 'default'}': params read {'.'.join(leaf)}, "
                                       "the planner's key does not")
    finally:
        g["RUN_CONFIGS"] = base_configs
    assert tried > 1000
    assert not mismatches, "\n".join(sorted(mismatches))
