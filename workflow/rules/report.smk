# summary.json (the paper-versus-reproduction numbers) and the HTML report.


rule summary:
    """Collect every stage's numbers into results/summary.json."""
    input:
        assemble="results/model/assemble.json",
        evidence=expand("results/ident/{subsystem}_evidence.json", subsystem=SUBSYSTEMS),
        uncertainty=expand("results/uncertainty/{subsystem}.json", subsystem=SUBSYSTEMS),
        mu=expand("results/mu/{case}.json", case=MU_CASES),
        baseline="results/mu/baseline.json",
        validation="results/validation/sweep.json",
        closeloop=expand("results/closeloop/{dataset}/closeloop.json", dataset=CLOSELOOP_DATASETS),
        sims=expand("results/sim/{experiment}.json", experiment=SIM_EXPERIMENTS),
    output:
        "results/summary.json",
    params:
        default_dataset=CLOSELOOP_DEFAULT,
    log:
        "results/logs/summary.log",
    benchmark:
        "results/benchmarks/summary.tsv"
    script:
        "../scripts/summary.py"


rule report:
    """Build the notebook from results/, execute it and render results/report.html (nbconvert)."""
    input:
        summary="results/summary.json",
        figures=[
            "results/model/fig4.png",
            "results/validation/fig9.png",
            *expand("results/uncertainty/{subsystem}_fig7.png", subsystem=SUBSYSTEMS),
            *expand("results/mu/{case}_fig8.png", case=MU_CASES),
            *expand("results/ident/{subsystem}_{kind}.png", subsystem=SUBSYSTEMS, kind=["orders", "validation"]),
            "results/sim/levitate.npz",
            "results/sim/multisine.npz",
        ],
        config_file="config.yaml",
        study="results/study/study.json",
    output:
        html="results/report.html",
        notebook="results/report.ipynb",
    params:
        closeloop_dir=(f"results/closeloop/{CLOSELOOP_DEFAULT}" if CLOSELOOP_DEFAULT else None),
    log:
        "results/logs/report.log",
    benchmark:
        "results/benchmarks/report.tsv"
    resources:
        mem_mb=3000,
        runtime=15,
    script:
        "../scripts/report.py"
