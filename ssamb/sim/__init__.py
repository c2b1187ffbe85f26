"""The nonlinear 2-DOF DCM self-sensing AMB simulator (paper section 2.2).

``simulate(cfg, experiment)`` is the entry point; see :mod:`ssamb.sim.api`. The names below are
loaded on first use: a program that only reads the device's description (the workflow's start,
which checks the configuration) does not import the simulator's compiled kernels.
"""
import importlib

__all__ = ["simulate", "SimOptions", "SimResult", "equilibrium", "calibrate_selfsensing", "delevitation_time",
           "AMBParams", "amb_params"]
_WHERE = {"AMBParams": ".params", "amb_params": ".params"}


def __getattr__(name: str):
    if name not in __all__:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(_WHERE.get(name, ".api"), __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
