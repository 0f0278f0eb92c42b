"""The operator programmes (static, impact, probe calibration, flow): their specs, the DC-level
drive they share (on the run's one AO stream, `control.run.stream.DriveStream`), the operator
protocol and the engine the daemon runs them behind."""
