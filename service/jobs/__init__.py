"""A job's life outside the HTTP layer: the runner that claims it, the worker code that runs it,
who owns it, what it ran with, its packaged result and the risk card an approver reads."""
