"""Executing approved plans: the robot bridge as the service sees it, and dispatch through it."""
