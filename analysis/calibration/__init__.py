"""The simulated rig against the reference report: run its test plan, compare with its tables,
fit the terms responsible (`compare`, `fit`, `plan`)."""
