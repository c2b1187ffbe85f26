r"""The 1-DOF levitated steel ball: a second device for close the loop.

A steel ball hangs below an electromagnet; an optical sensor measures its position :math:`y`
(downwards from the magnet's face), a shunt the coil current :math:`i`, and a digital controller
at 100 Hz (a position PID whose output is the current demand of a current PI) sets the coil
voltage :math:`u` through a PWM stage. The rig and its data come from the public repository
JRavenelco/levitador-benchmark (MIT licence; ``resources/maglev1d/NOTICE``).

Modules
-------
:mod:`.data`
    The file formats (the rig's text logs, a plain CSV, the converted NPZ), their checks, and
    when the ball levitates.
:mod:`.controller`
    The rig's controller, reconstructed from its acquisition program, and the check that the
    logged command follows from the logged signals.
:mod:`.physics`
    The model: gravity, the reluctance force of the inductance-versus-gap law, the coil with its
    motion term, the stops, the sensors' quantisation, the controller; a compiled replay.
:mod:`.config`
    The device configuration (``config.yaml``, package data).
:mod:`.device`
    :class:`~ssamb.maglev1d.device.Maglev1D`, the :class:`ssamb.device.Device` of close the loop.
:mod:`.effects`
    The effect library, one module per effect.
:mod:`.checks`
    Physical checks of the model against the data (the coil's time constant, the equilibrium
    current against the gap, the linearised loop's stability).
"""
