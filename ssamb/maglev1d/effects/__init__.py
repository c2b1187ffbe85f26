r"""The levitated ball's effect library: what real levitation rigs are known to have and the
nominal model lacks, one module per effect (:data:`MODULES`).

Each module (the interface :class:`ssamb.device.EffectModule`) holds its parameters and their
validation, how it enters the replay (``apply(knobs, effect, cfg)``: it sets its knobs of the
compiled model, :data:`ssamb.maglev1d.physics.KNOBS`), the signature it leaves in the residual
and the evidence for it, its parameterisation for fitting and its entry in ``closeloop.json``.

==================== ============================ ==================================================
name                 parameters                   physics
==================== ============================ ==================================================
sensor_delay         delay_s                      the position reaches the controller late
actuation_delay      delay_s                      the new command reaches the coil late
sensor_gain          gain                         the position sensor's scale error
sensor_offset        offset_m                     the position sensor's zero off the magnet's face
static_load          fy_n                         a constant extra force (downwards positive)
eddy_current         tau_s                        a core-loss branch: the force lags the current
saturation           coefficient_per_a2           the force grows slower than i^2 at high current
amplifier_drop       drop_v                       the PWM stage's switch and diode drops
current_offset       offset_a                     the current reading's offset
resistance_drift     rate_ohm_per_s               the coil's resistance grows as it warms
remanence            mmf_a                        the core's remanent magnetisation, an MMF beside the coil's
==================== ============================ ==================================================

The views the evidence reads: offsets of ``y``, ``i``, ``u`` (force-like effects shift ``i``
and ``u``, the stage's drop ``u`` alone, the current sensor ``i`` alone; the position loop's
integral action holds ``y``), the measured/model ratios of the paths ``y/i`` (the mechanics and
the position sensor) and ``i/u`` (the coil and the stage), and the window means of ``u`` and
``i`` (slow drifts).
"""
from . import (actuation_delay, amplifier_drop, current_offset, eddy_current, remanence, resistance_drift,
               saturation, sensor_delay, sensor_gain, sensor_offset, static_load)
from ._common import EffectError

__all__ = ["MODULES", "EffectError"]

#: the effect modules, in the order close the loop ranks ties
MODULES = (sensor_delay, actuation_delay, sensor_gain, sensor_offset, static_load, eddy_current, saturation,
           amplifier_drop, current_offset, resistance_drift, remanence)
