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
"""
