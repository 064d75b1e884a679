"""Grasps of an object by a jaw (object-frame reference data, computed once per object) and
dual-arm handover poses."""
