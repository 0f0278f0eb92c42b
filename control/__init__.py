"""Shaker control, one room an idea (the import-linter contracts in pyproject.toml hold them):

- `control.signal`: synthesis, lock-in, amplitude controller. Algorithms, no I/O, no siblings.
- `control.run`: a run on the rig. Shared by both kinds of run: the `Listener` stream and its
  `FanOut` (`listener`), the drive stream (`stream`) and where its AO goes (`ao_writer`),
  `safety`, the `pump` interlock, the errors raised while running (`errors`), the run's file
  (`files`) and `summary`. `control.run.sweep`: the sine sweep (engine, dwell, approach, states,
  step_result, dwell_states). `control.run.programs`: the operator programmes (specs, their DC
  levels on the run's drive stream, the operator protocol, procedures, impact, static by hand,
  the engine the daemon runs).
- `control.daemon`: the daemon, its state machine, its commands, the acquisition thread, the
  one-instance locks.
- `control.wire`: what crosses the network: protocol, client, publisher, security, safe text, the
  sweep request (`sweep_spec`, `step_plan`), the refusals (`errors`) and the lock-in clients
  apply to the blocks (`harmonics`). Imports only `control.signal`; clients import only it.
- `control.commissioning`: `sfdrig commission` (procedure and checks).
"""
