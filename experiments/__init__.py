"""Experiments: the paper's reproduction (``regrasp paper``), its claims, its ablations, and the
figures every command draws (:mod:`experiments.plots`, :mod:`experiments.convergence_plot`).

Beside ``service/``: it depends on ``planner/`` through its public functions (scenarios, plans,
surveys) and never on the service; the service's CLI and demo call it.
"""
