"""The sine sweep (its request is `control.wire.sweep_spec`): the engine, each dwell (approach,
converge, settle, record)."""
