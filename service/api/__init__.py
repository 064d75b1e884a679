"""HTTP routes of the planning service, one module per resource."""
