# Parameter study: the mu margin and the delevitation amplitude over one parameter
# (config study.parameter, one job per value in study.values).

STUDY = config.get("study", {"parameter": None, "values": []})
STUDY_VALUES = [f"{float(v):g}" for v in STUDY["values"]]


def study_config(wildcards=None):
    """Everything the chain needs (physics, experiments, analysis settings), not the data sets."""
    return section(*SIM_SECTIONS, "experiments", "identification", "assembly", "uncertainty", "mu", "validation")


rule study_point:
    """The analysis chain for one value of the study parameter (ssamb.stages.study.run_study_point)."""
    output:
        "results/study/point_{value}.json",
    params:
        cfg=study_config,
        parameter=STUDY["parameter"],
    log:
        "results/logs/study/{value}.log",
    benchmark:
        "results/benchmarks/study/{value}.tsv"
    wildcard_constraints:
        value="[-+0-9.eE]+",
    threads: 1
    resources:
        mem_mb=4000,
        runtime=30,
    script:
        "../scripts/study_point.py"


rule study:
    """Gather the study points into results/study/study.json and a figure."""
    input:
        expand("results/study/point_{value}.json", value=STUDY_VALUES),
    output:
        json="results/study/study.json",
        fig="results/study/study.png",
    log:
        "results/logs/study/collect.log",
    benchmark:
        "results/benchmarks/study/collect.tsv"
    script:
        "../scripts/study.py"
