rule simulate:
    """Nonlinear 2-DOF DCM self-sensing AMB simulation of one experiment (paper section 2.2)."""
    output:
        npz="results/sim/{experiment}.npz",
        meta="results/sim/{experiment}.json",
    params:
        cfg=sim_config,
    log:
        "results/logs/simulate/{experiment}.log",
    benchmark:
        "results/benchmarks/simulate/{experiment}.tsv"
    wildcard_constraints:
        experiment="[A-Za-z0-9_]+",
    resources:
        mem_mb=2000,
        runtime=30,
    script:
        "../scripts/simulate.py"
