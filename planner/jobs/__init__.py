"""Jobs: a scenario and its overrides in, a plan or survey document out; the functions the
service's workers call."""
