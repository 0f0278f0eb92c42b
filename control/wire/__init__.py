"""What crosses the network: the wire protocol, the client library, the publisher framing, CURVE
security and text made safe. The only part of `control` that clients (`web`, the CLI) import."""
