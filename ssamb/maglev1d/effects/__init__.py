r"""The levitated ball's effect library: what real levitation rigs are known to have and the
nominal model lacks, one module per effect (found by :func:`ssamb.device.effect_modules`:
adding an effect is adding its module and a test).

Each module (the interface :class:`ssamb.device.EffectModule`) holds its parameters and their
validation, how it enters the replay (``apply(knobs, effect, cfg)``: it sets its knobs of the
compiled model, :data:`ssamb.maglev1d.physics.KNOBS`), the signature it leaves in the residual
and the evidence for it, its parameterisation for fitting and its entry in ``closeloop.json``;
its docstring states the physics.

The views the evidence reads: offsets of ``y``, ``i``, ``u`` (force-like effects shift ``i``
and ``u``, the stage's drop ``u`` alone, the current sensor ``i`` alone; the position loop's
integral action holds ``y``), the measured/model ratios of the paths ``y/i`` (the mechanics and
the position sensor) and ``i/u`` (the coil and the stage), and the window means of ``u`` and
``i`` (slow drifts).
"""
from ._common import EffectError

__all__ = ["EffectError"]
