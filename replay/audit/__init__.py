"""The audit: a task checked for state that its state dict does not capture (`audit`: `audit_task`), by the checks
in `checks`, also along real trajectories (`trajectory`)."""
