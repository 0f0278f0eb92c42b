"""The sine sweep: its spec and plan, the engine, each dwell (approach, converge, settle,
record)."""
