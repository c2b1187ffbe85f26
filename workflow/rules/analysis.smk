# The paper's analysis chain: identify -> assemble -> uncertainty -> mu -> validate, per run.
# Each rule calls one ssamb.stages function (see the scripts); config values arrive via params.


def mu_cases(run):
    return list(RUN_CONFIGS[run]["mu"]["cases"])


def mu_settings(wc):
    """Params: the mu section without its list of cases (which selects the jobs; a job reads its own)."""
    return {k: v for k, v in cfg_of(wc)["mu"].items() if k != "cases"}


rule identify:
    """SIPPY model of one subsystem (paper section 3): method comparison, order scan, paper variant."""
    input:
        est=lambda wc: sim_file(wc.run, cfg_of(wc)["identification"]["estimation"]),
        val=lambda wc: sim_file(wc.run, cfg_of(wc)["identification"]["validation"]),
    output:
        model="results/{run}ident/{subsystem}.npz",
        evidence="results/{run}ident/{subsystem}_evidence.json",
        paper_variant="results/{run}ident/{subsystem}_paper.npz",
        fig_orders="results/{run}ident/{subsystem}_orders.png",
        fig_validation="results/{run}ident/{subsystem}_validation.png",
        candidates="results/{run}ident/{subsystem}_candidates.npz",
    params:
        identification=lambda wc: identification_config(cfg_of(wc), wc.subsystem),
    log:
        "results/{run}logs/identify/{subsystem}.log",
    benchmark:
        "results/{run}benchmarks/identify/{subsystem}.tsv"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=20,
    script:
        "../scripts/identify.py"


rule select:
    """The three models chosen by the stability and validation fit of the assembled loop
    (config identification.selection: loop; the paper's structures need it)."""
    input:
        candidates=lambda wc: [out("identify", wc.run, f"ident/{s}_candidates.npz", subsystem=s) for s in SUBSYSTEMS],
        val=lambda wc: sim_file(wc.run, cfg_of(wc)["identification"]["validation"]),
    output:
        models=expand("results/{{run}}select/{subsystem}.npz", subsystem=SUBSYSTEMS),
        json="results/{run}select/select.json",
    params:
        pid=section("table1", "controller"),
    log:
        "results/{run}logs/select.log",
    benchmark:
        "results/{run}benchmarks/select.tsv"
    resources:
        mem_mb=3000,
        runtime=20,
    script:
        "../scripts/select.py"


rule assemble:
    """Closed-loop LTI model (Fig. 3), its stability, the d2c error and the Fig. 4 comparison."""
    input:
        models=lambda wc: model_files(wc.run),
        paper=lambda wc: model_files(wc.run, "_paper"),
        fig4=lambda wc: sim_file(wc.run, cfg_of(wc)["assembly"]["fig4"]),
    output:
        discrete="results/{run}model/closed_loop.npz",
        json="results/{run}model/assemble.json",
        fig="results/{run}model/fig4.png",
    params:
        pid=section("table1", "controller"),
        assembly=lambda wc: cfg_of(wc)["assembly"],
    log:
        "results/{run}logs/assemble.log",
    benchmark:
        "results/{run}benchmarks/assemble.tsv"
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/assemble.py"


rule uncertainty:
    """ETFE of the additive mismatch of one subsystem and its weight W(s) (paper section 5, Fig. 7)."""
    input:
        multisine=lambda wc: sim_file(wc.run, cfg_of(wc)["uncertainty"]["experiment"]),
        closed_loop=lambda wc: out("assemble", wc.run, "model/closed_loop.npz"),
        selfsensing=lambda wc: model_files(wc.run)[SUBSYSTEMS.index("selfsensing")],
    output:
        weight="results/{run}uncertainty/{subsystem}_weight.npz",
        json="results/{run}uncertainty/{subsystem}.json",
        fig="results/{run}uncertainty/{subsystem}_fig7.png",
    params:
        uncertainty=lambda wc: cfg_of(wc)["uncertainty"],
    log:
        "results/{run}logs/uncertainty/{subsystem}.log",
    benchmark:
        "results/{run}benchmarks/uncertainty/{subsystem}.tsv"
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/uncertainty.py"


def mu_inputs(wc):
    subs = SUBSYSTEMS if wc.case == "all" else (wc.case,)
    files = dict(zip(("plant_model", "amplifier_model", "selfsensing_model"), model_files(wc.run)))
    files.update({f"w_{s}": weight_file(wc.run, s) for s in subs})
    return files


rule mu:
    """Structured singular value over frequency for one uncertainty case (paper section 4, Fig. 8)."""
    input:
        unpack(mu_inputs),
    output:
        json="results/{run}mu/{case}.json",
        curve="results/{run}mu/{case}_curve.npz",
        fig="results/{run}mu/{case}_fig8.png",
    params:
        pid=section("table1", "controller"),
        mu=mu_settings,
    log:
        "results/{run}logs/mu/{case}.log",
    benchmark:
        "results/{run}benchmarks/mu/{case}.tsv"
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/mu.py"


rule baseline:
    """ISO 14839-3 peak sensitivity per axis and classical margins (the baseline the paper argues against)."""
    input:
        models=lambda wc: model_files(wc.run),
    output:
        json="results/{run}mu/baseline.json",
    params:
        pid=section("table1", "controller"),
        mu=mu_settings,
    log:
        "results/{run}logs/baseline.log",
    benchmark:
        "results/{run}benchmarks/baseline.tsv"
    script:
        "../scripts/baseline.py"


rule validate:
    """Augmented models and the delevitation sweep (paper section 6, Fig. 9)."""
    input:
        sweep=lambda wc: sim_file(wc.run, "sweep"),
        models=lambda wc: model_files(wc.run),
        weight=lambda wc: weight_file(wc.run, cfg_of(wc)["validation"]["weight"]),
    output:
        json="results/{run}validation/sweep.json",
        fig="results/{run}validation/fig9.png",
    params:
        sim=lambda wc: _sim_config(cfg_of(wc), "sweep"),
        validation=lambda wc: cfg_of(wc)["validation"],
    log:
        "results/{run}logs/validate.log",
    benchmark:
        "results/{run}benchmarks/validate.tsv"
    resources:
        mem_mb=2000,
        runtime=20,
    script:
        "../scripts/validate.py"
