"""The regrasp problem: the graph of placements x grasps (single-arm regrasp, dual-arm handover),
its lazy search, node and edge validation, and assembly of the plan's trajectory."""
