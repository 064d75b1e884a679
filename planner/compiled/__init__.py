"""Compiled inner loops (numba): the joint-tree walk and CoM sum, the box collision screen, the IK
descent. Pure array kernels; the domain code calls them through planner.kinematics and
planner.scene.collision."""
