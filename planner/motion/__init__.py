"""Motion: inverse kinematics, the energy-based T-RRT planner, path shortcutting, and time
parametrisation within velocity, acceleration and ZMP limits."""
