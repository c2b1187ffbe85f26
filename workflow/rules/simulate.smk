rule simulate:
    """Nonlinear 2-DOF DCM self-sensing AMB simulation of one experiment (paper section 2.2)."""
    output:
        npz="results/{run}sim/{experiment}.npz",
        meta="results/{run}sim/{experiment}.json",
    params:
        cfg=sim_config,
    log:
        "results/{run}logs/simulate/{experiment}.log",
    benchmark:
        "results/{run}benchmarks/simulate/{experiment}.tsv"
    resources:
        mem_mb=2000,
        runtime=30,
    script:
        "../scripts/simulate.py"
