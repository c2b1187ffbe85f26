"""The workflow stages: file in, file out, nothing else.

One module per Snakemake rule family; each ``run_*`` function reads its input files, calls the
numerics of the core modules and writes its output files (atomically). Whatever a rule does, a
user can do from Python with the same function. Only the workflow scripts and the CLI import
these modules; the core modules never do.

=============== ============================== ==========================================
module          rule                           numerics
=============== ============================== ==========================================
simulate        ``simulate`` (per experiment)   :mod:`ssamb.sim`
identify        ``identify`` (per subsystem)    :mod:`ssamb.identification`
select          ``select`` (paper's way)        :mod:`ssamb.identification.joint`
assemble        ``assemble``                    :mod:`ssamb.closed_loop`
uncertainty     ``uncertainty`` (per subsystem) :mod:`ssamb.uncertainty`
mu              ``mu`` (per case)               :mod:`ssamb.generalized_plant`, :mod:`ssamb.robustness`
baseline        ``baseline``                    :mod:`ssamb.robustness`
validate        ``validate``                    :mod:`ssamb.validation`
summary         ``summary``                     (collects the stage outputs)
=============== ============================== ==========================================
"""
