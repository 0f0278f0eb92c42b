"""CURVE security for the daemon's sockets: key directories, the ZAP authenticator, client keys.

The daemon binds to loopback by default and then needs no keys. Binding to any other interface
requires a key directory made by ``sfdrig keys DIR``::

    DIR/server.key              the daemon's public key (give it to every client)
    DIR/server.key_secret       the daemon's secret key (stays on the rig PC)
    DIR/commanders/NAME.key     public keys allowed to send commands (and to read live data)
    DIR/readers/NAME.key        public keys allowed to read live data only
    DIR/clients/NAME.key_secret each client's key pair (hand it to that client only)

The authenticator reads the allowed-key directories at every connection, so adding or removing a
key file takes effect without restarting the daemon. A client whose key is not in the directory
fails the CURVE handshake: its commands never reach the daemon.
"""

from __future__ import annotations

import ipaddress
import os
import re
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

COMMAND_DOMAIN = "sfdrig-commands"
DATA_DOMAIN = "sfdrig-data"


class KeyFileError(ValueError):
    """A key directory or key file is missing or unreadable; the message names the path."""


@dataclass(frozen=True)
class ServerKeys:
    """The daemon's key pair and where the authorised client keys live."""

    public: bytes
    secret: bytes
    directory: Path


@dataclass(frozen=True)
class ClientKeys:
    """A client's key pair and the daemon's public key (z85 bytes)."""

    public: bytes
    secret: bytes
    server_public: bytes


def _write_cert(path: Path, public: bytes, secret: bytes | None) -> None:
    lines = ["#   sfdrig CURVE certificate (ZeroMQ zcert format)", "metadata", "curve",
             f'    public-key = "{public.decode()}"']
    if secret is not None:
        lines.append(f'    secret-key = "{secret.decode()}"')
    path.write_text("\n".join(lines) + "\n")
    if secret is not None:
        os.chmod(path, 0o600)


def make_keys(directory: str | Path, commanders: list[str], readers: list[str]) -> list[Path]:
    """Create the server key pair and one key pair per client in ``directory``.

    Parameters
    ----------
    directory : path
        Created if absent. Existing key files are never overwritten; an existing server key is
        kept, so the command adds clients to a directory.
    commanders, readers : list of str
        Client names allowed to command (and read), or to read live data only.

    Returns
    -------
    list of Path
        The files written.
    """
    d = Path(directory)
    for sub in ("commanders", "readers", "clients"):
        (d / sub).mkdir(parents=True, exist_ok=True)
    overlap = set(commanders) & set(readers)
    if overlap:
        raise KeyFileError(f"names both commander and reader: {sorted(overlap)}")
    for name in [*commanders, *readers]:
        if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}", name):
            raise KeyFileError(f"client name {name!r} must be 1-64 letters, digits, '_', '.' "
                               "or '-', not starting with '.' or '-'")
        if (d / "clients" / f"{name}.key_secret").exists():
            raise KeyFileError(f"{d / 'clients' / (name + '.key_secret')} exists; remove it "
                               "first to make a new key")
    written: list[Path] = []

    def new(path: Path, public_path: Path | None) -> None:
        if path.exists():
            raise KeyFileError(f"{path} exists; remove it first to make a new key")
        public, secret = zmq.curve_keypair()
        _write_cert(path, public, secret)
        written.append(path)
        if public_path is not None:
            _write_cert(public_path, public, None)
            written.append(public_path)

    if not (d / "server.key_secret").exists():  # an existing directory keeps its server key
        new(d / "server.key_secret", d / "server.key")
    for name in commanders:
        new(d / "clients" / f"{name}.key_secret", d / "commanders" / f"{name}.key")
    for name in readers:
        new(d / "clients" / f"{name}.key_secret", d / "readers" / f"{name}.key")
    return written


def _load(path: Path, need_secret: bool) -> tuple[bytes, bytes | None]:
    if not path.is_file():
        raise KeyFileError(f"key file {path} not found (make keys with `sfdrig keys DIR`)")
    try:
        public, secret = zmq.auth.load_certificate(str(path))
    except (OSError, ValueError) as err:
        raise KeyFileError(f"key file {path} is not a CURVE certificate: {err}") from None
    if need_secret and not secret:
        raise KeyFileError(f"key file {path} holds no secret key")
    return public, secret


def load_server_keys(directory: str | Path) -> ServerKeys:
    d = Path(directory)
    public, secret = _load(d / "server.key_secret", need_secret=True)
    assert secret is not None
    return ServerKeys(public, secret, d)


def load_client_keys(directory: str | Path, name: str) -> ClientKeys:
    """A client's keys: ``DIR/clients/NAME.key_secret`` and the server's ``DIR/server.key``."""
    d = Path(directory)
    public, secret = _load(d / "clients" / f"{name}.key_secret", need_secret=True)
    server_public, _ = _load(d / "server.key", need_secret=False)
    assert secret is not None
    return ClientKeys(public, secret, server_public)


def _public_keys(*dirs: Path) -> set[bytes]:
    keys: set[bytes] = set()
    for d in dirs:
        for f in sorted(d.glob("*.key")) if d.is_dir() else []:
            try:
                keys.add(zmq.auth.load_certificate(str(f))[0])
            except (OSError, ValueError):
                continue  # an unreadable key authorises nobody
    return keys


class _AllowedKeys:
    """ZAP credentials provider: the public keys found in some directories, read per handshake."""

    def __init__(self, *dirs: Path) -> None:
        self.dirs = dirs

    def callback(self, domain: str, key: bytes) -> bool:
        return key in _public_keys(*self.dirs)


def start_authenticator(ctx: zmq.Context, keys: ServerKeys) -> ThreadAuthenticator:
    """Start ZAP: commanders may command, commanders and readers may subscribe."""
    auth = ThreadAuthenticator(ctx)
    auth.start()
    cmd_dir, read_dir = keys.directory / "commanders", keys.directory / "readers"
    auth.configure_curve_callback(COMMAND_DOMAIN, _AllowedKeys(cmd_dir))
    auth.configure_curve_callback(DATA_DOMAIN, _AllowedKeys(cmd_dir, read_dir))
    return auth


def secure_server_socket(sock: zmq.Socket, keys: ServerKeys, domain: str) -> None:
    """Make ``sock`` a CURVE server in ZAP ``domain`` (call before bind)."""
    sock.curve_secretkey = keys.secret
    sock.curve_publickey = keys.public
    sock.curve_server = True
    sock.zap_domain = domain.encode()


def secure_client_socket(sock: zmq.Socket, keys: ClientKeys) -> None:
    """Make ``sock`` a CURVE client of the server whose public key ``keys`` holds."""
    sock.curve_secretkey = keys.secret
    sock.curve_publickey = keys.public
    sock.curve_serverkey = keys.server_public


def is_loopback(endpoint: str) -> bool:
    """True for ipc://, inproc:// and tcp:// on 127.0.0.0/8, ::1 or localhost."""
    parts = urlsplit(endpoint)
    if parts.scheme in ("ipc", "inproc"):
        return True
    if parts.scheme != "tcp":
        return False
    host = parts.hostname or ""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # an interface name or "*": not provably loopback
