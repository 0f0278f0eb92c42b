"""What crosses the network: the wire protocol, the client library, the publisher framing, CURVE
security and text made safe; the sweep request (`sweep_spec`, `step_plan`) and the refusals a
client sees (`errors`); the lock-in a client applies to the published blocks (`harmonics`). The
only part of `control` that clients (`web`, the CLI's client commands) import."""
