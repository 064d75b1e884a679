"""The physics twin: the robot in MuJoCo, with servos, sole contacts, the held load and a stabilizer.

It stands behind the simulated controller (``controller-sim --plant physics``) and plays plans offline
(``regrasp simulate``). It reads the robot's URDF and spec as data and never imports the planner; the safety
gate never imports it (docs/physics.md states every modelling choice).
"""
