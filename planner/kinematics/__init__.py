"""Forward kinematics of many configurations at once, over the robot model's joint tree (the one
adapter from the model to the compiled kernels)."""
