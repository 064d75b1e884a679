"""Compiled inner loops (numba): the joint-tree walk and CoM sum, the box collision screen, the IK
descent, the T-RRT trees' nearest-node search. Pure array kernels; the domain code calls them
through planner.kinematics, planner.scene.collision and planner.motion."""
