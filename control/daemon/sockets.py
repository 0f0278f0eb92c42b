"""The daemon's two sockets: the ROUTER for commands and the PUB for data, bound, with CURVE
security when keys are given (and required beyond this computer)."""

from __future__ import annotations

import zmq
from zmq.auth.thread import ThreadAuthenticator

from control.wire.protocol import MAX_FRAME_BYTES
from control.wire.security import (
    COMMAND_DOMAIN,
    DATA_DOMAIN,
    ServerKeys,
    is_loopback,
    secure_server_socket,
    start_authenticator,
)


def bind_sockets(ctx: zmq.Context, command_endpoint: str, data_endpoint: str,
                 keys: ServerKeys | None, sndhwm: int
                 ) -> tuple[zmq.Socket, zmq.Socket, dict[str, str], ThreadAuthenticator | None]:
    """(command socket, data socket, their endpoints as bound, the ZAP authenticator or None).
    ``sndhwm``: the PUB socket's send high-water mark [messages]; 0 = unlimited."""
    for ep in (command_endpoint, data_endpoint):
        if not is_loopback(ep) and keys is None:
            raise PermissionError(
                f"binding {ep} exposes the rig beyond this computer: CURVE keys are required "
                f"(make them with `sfdrig keys DIR`, then pass --keys DIR)"
            )
    auth = start_authenticator(ctx, keys) if keys is not None else None
    command = ctx.socket(zmq.ROUTER)
    data = ctx.socket(zmq.PUB)
    for s in (command, data):
        s.linger = 500
    command.router_mandatory = False
    command.maxmsgsize = MAX_FRAME_BYTES  # a bigger frame drops its peer, unread
    data.sndhwm = sndhwm
    if keys is not None:
        secure_server_socket(command, keys, COMMAND_DOMAIN)
        secure_server_socket(data, keys, DATA_DOMAIN)
    endpoints = {}
    for name, sock, ep in (("command", command, command_endpoint),
                           ("data", data, data_endpoint)):
        sock.bind(_random_port(ep))
        endpoints[name] = str(sock.getsockopt_string(zmq.LAST_ENDPOINT))
    return command, data, endpoints, auth


def _random_port(endpoint: str) -> str:
    """``tcp://host:0`` -> ``tcp://host:*`` (ZeroMQ's any-free-port)."""
    return endpoint[:-2] + ":*" if endpoint.startswith("tcp://") and endpoint.endswith(":0") \
        else endpoint
