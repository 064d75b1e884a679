"""The planner's public interface: what the service (and anything else outside the planner) may use.

Everything else under ``planner/`` is internal and may change without notice; an architecture test
holds ``service/`` to this package and :mod:`planner.errors`. The interface is split by concern so
that importing one part does not import the rest (the planning code takes seconds to import):

- :mod:`planner.api.catalogue`: what a request can name (robots, scenarios, stances, meshes) and the
  checks of those names;
- :mod:`planner.api.robots`: a robot's model, its description and spec files, the compiled kernels' warm-up;
- :mod:`planner.api.jobs`: planning and surveying (the workers' entry points, the CLI's runs).
"""
