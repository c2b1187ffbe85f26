"""The nonlinear 2-DOF DCM self-sensing AMB simulator (paper section 2.2).

``simulate(cfg, experiment)`` is the entry point; see :mod:`ssamb.sim.api`.
"""
from .api import SimOptions, SimResult, calibrate_selfsensing, delevitation_time, equilibrium, simulate
from .params import AMBParams, amb_params

__all__ = ["simulate", "SimOptions", "SimResult", "equilibrium", "calibrate_selfsensing", "delevitation_time",
           "AMBParams", "amb_params"]
