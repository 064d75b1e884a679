"""Robot models: spec files, the generated URDFs, and the pinocchio model with the frames and limits the planner needs."""
