"""The scene: objects and their mass properties, resting placements on tables, collision checking,
and the scenario files that describe a task."""
