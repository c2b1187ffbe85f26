# The paper's analysis chain: identify -> assemble -> uncertainty -> mu -> validate.
# Each rule calls one ssamb function (see the scripts); config values arrive via params.

SUBSYSTEMS = ["plant", "amplifier", "selfsensing"]
MU_CASES = list(config["mu"]["cases"])


def exp_file(key_path):
    """results/sim/<experiment>.npz for the experiment named at a dotted config key."""
    node = config
    for k in key_path.split("."):
        node = node[k]
    return f"results/sim/{node}.npz"


def pid_config(wildcards=None):
    """What the discrete PID needs (Table 1 gains, controller rate and derivative filter)."""
    return section("table1", "controller")


rule identify:
    """SIPPY model of one subsystem (paper section 3): method comparison, order scan, paper variant."""
    input:
        est=exp_file("identification.estimation"),
        val=exp_file("identification.validation"),
    output:
        model="results/ident/{subsystem}.npz",
        evidence="results/ident/{subsystem}_evidence.json",
        paper_variant="results/ident/{subsystem}_paper.npz",
        fig_orders="results/ident/{subsystem}_orders.png",
        fig_validation="results/ident/{subsystem}_validation.png",
    params:
        identification=lambda wc: section("identification")["identification"],
    log:
        "results/logs/identify/{subsystem}.log",
    benchmark:
        "results/benchmarks/identify/{subsystem}.tsv"
    wildcard_constraints:
        subsystem="plant|amplifier|selfsensing",
    threads: 1
    resources:
        mem_mb=4000,
        runtime=20,
    script:
        "../scripts/identify.py"


rule assemble:
    """Closed-loop LTI model (Fig. 3), its continuous equivalent and the Fig. 4 comparison."""
    input:
        models=expand("results/ident/{subsystem}.npz", subsystem=SUBSYSTEMS),
        paper=expand("results/ident/{subsystem}_paper.npz", subsystem=SUBSYSTEMS),
        fig4=exp_file("assembly.fig4"),
    output:
        discrete="results/model/closed_loop.npz",
        json="results/model/assemble.json",
        fig="results/model/fig4.png",
    params:
        pid=pid_config,
        assembly=lambda wc: section("assembly")["assembly"],
    log:
        "results/logs/assemble.log",
    benchmark:
        "results/benchmarks/assemble.tsv"
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/assemble.py"


rule uncertainty:
    """ETFE of the additive mismatch of one subsystem and its weight W(s) (paper section 5, Fig. 7)."""
    input:
        multisine=exp_file("uncertainty.experiment"),
        closed_loop="results/model/closed_loop.npz",
        selfsensing="results/ident/selfsensing.npz",
    output:
        weight="results/uncertainty/{subsystem}_weight.npz",
        json="results/uncertainty/{subsystem}.json",
        fig="results/uncertainty/{subsystem}_fig7.png",
    params:
        uncertainty=lambda wc: section("uncertainty")["uncertainty"],
    log:
        "results/logs/uncertainty/{subsystem}.log",
    benchmark:
        "results/benchmarks/uncertainty/{subsystem}.tsv"
    wildcard_constraints:
        subsystem="plant|amplifier|selfsensing",
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/uncertainty.py"


def mu_weights(wildcards):
    subs = SUBSYSTEMS if wildcards.case == "all" else [wildcards.case]
    return {f"w_{s}": f"results/uncertainty/{s}_weight.npz" for s in subs}


rule mu:
    """Structured singular value over frequency for one uncertainty case (paper section 4, Fig. 8)."""
    input:
        unpack(mu_weights),
        plant_model="results/ident/plant.npz",
        amplifier_model="results/ident/amplifier.npz",
        selfsensing_model="results/ident/selfsensing.npz",
    output:
        json="results/mu/{case}.json",
        curve="results/mu/{case}_curve.npz",
        fig="results/mu/{case}_fig8.png",
    params:
        pid=pid_config,
        mu=lambda wc: section("mu")["mu"],
    log:
        "results/logs/mu/{case}.log",
    benchmark:
        "results/benchmarks/mu/{case}.tsv"
    wildcard_constraints:
        case="selfsensing|amplifier|plant|all",
    resources:
        mem_mb=2000,
        runtime=10,
    script:
        "../scripts/mu.py"


rule baseline:
    """ISO 14839-3 peak sensitivity per axis and classical margins (the baseline the paper argues against)."""
    input:
        models=expand("results/ident/{subsystem}.npz", subsystem=SUBSYSTEMS),
    output:
        json="results/mu/baseline.json",
    params:
        pid=pid_config,
        mu=lambda wc: section("mu")["mu"],
    log:
        "results/logs/baseline.log",
    benchmark:
        "results/benchmarks/baseline.tsv"
    script:
        "../scripts/baseline.py"


rule validate:
    """Augmented models and the delevitation sweep (paper section 6, Fig. 9)."""
    input:
        sweep="results/sim/sweep.npz",
        models=expand("results/ident/{subsystem}.npz", subsystem=SUBSYSTEMS),
        weight=lambda wc: f"results/uncertainty/{config['validation']['weight']}_weight.npz",
    output:
        json="results/validation/sweep.json",
        fig="results/validation/fig9.png",
    params:
        sim=lambda wc: {**sim_config(), "experiments": {"sweep": config["experiments"]["sweep"]}},
        validation=lambda wc: section("validation")["validation"],
    log:
        "results/logs/validate.log",
    benchmark:
        "results/benchmarks/validate.tsv"
    resources:
        mem_mb=2000,
        runtime=20,
    script:
        "../scripts/validate.py"
