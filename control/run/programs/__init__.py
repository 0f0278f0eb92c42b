"""The operator programmes (static, impact, probe calibration, flow): their specs, the DC-level
stream they share, the operator protocol and the engine the daemon runs them behind."""
