"""Who may look and who may act: the daemon's own operator/viewer roles, for browsers.

Without a key directory the web server serves loopback only, and every browser gets the one role
given on the command line (operator by default; ``viewer`` for a display that must not act).

With a key directory (``sfdrig keys DIR``, the daemon's) every browser logs in with its client
key file ``DIR/clients/NAME.key_secret``: the server derives the public key from the secret one
and looks it up, at every login, in ``DIR/commanders/`` (operator) and ``DIR/readers/`` (viewer),
exactly as the daemon's authenticator does for ZeroMQ clients. A session is a random token in an
HttpOnly, SameSite=Strict cookie; it holds the key's public half, and every request of the session
looks that key up again (`role_of_public_key`): removing a key file ends its sessions at once (the
server also closes their open WebSockets within a second), moving it changes their role.
"""

from __future__ import annotations

import re
import secrets
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth

OPERATOR = "operator"
VIEWER = "viewer"
ROLES = (OPERATOR, VIEWER)
COOKIE = "sfdrig_session"
_SECRET_RE = re.compile(r'secret-key\s*=\s*"([^"]{40})"')


class LoginRefused(ValueError):
    """The key file offered at login authorises nobody; the message says why (never the key)."""


@dataclass(frozen=True)
class Session:
    name: str
    role: str
    expires: float
    public_key: bytes = b""  # the key the session logged in with ("" without login)


def role_of_key_file(text: str, key_dir: Path) -> tuple[str, str, bytes]:
    """(client name, role, public key) of an uploaded ``NAME.key_secret`` file's text.

    Raises
    ------
    LoginRefused
        if the text holds no secret key or its public key is in neither role directory.
    """
    m = _SECRET_RE.search(text)
    if m is None:
        raise LoginRefused("not a key file: no secret-key line (use clients/NAME.key_secret "
                           "made by `sfdrig keys`)")
    try:
        public = zmq.curve_public(m.group(1).encode())
    except (ValueError, zmq.ZMQError):
        raise LoginRefused("not a key file: the secret key is not a CURVE key") from None
    found = role_of_public_key(public, key_dir)
    if found is None:
        raise LoginRefused("this key is not authorised (not in commanders/ or readers/)")
    return (*found, public)


def role_of_public_key(public: bytes, key_dir: Path) -> tuple[str, str] | None:
    """(client name, role) of a CURVE public key in ``key_dir`` now, None if in neither role
    directory (never authorised, or revoked since)."""
    for role, sub in ((OPERATOR, "commanders"), (VIEWER, "readers")):
        for f in sorted((key_dir / sub).glob("*.key")):
            try:
                if zmq.auth.load_certificate(str(f))[0] == public:
                    return f.stem, role
            except (OSError, ValueError):
                continue  # an unreadable key authorises nobody
    return None


class Sessions:
    """Login sessions of browsers, in memory (a restart logs everybody out)."""

    def __init__(self, lifetime_s: float = 12 * 3600) -> None:
        self.lifetime_s = lifetime_s
        self._lock = threading.Lock()
        self._sessions: dict[str, Session] = {}

    def new(self, name: str, role: str, public_key: bytes = b"") -> str:
        token = secrets.token_urlsafe(32)
        now = time.time()
        with self._lock:
            for t in [t for t, s in self._sessions.items() if s.expires < now]:
                del self._sessions[t]  # expired sessions never pile up
            self._sessions[token] = Session(name, role, now + self.lifetime_s, public_key)
        return token

    def get(self, token: str | None) -> Session | None:
        if not token:
            return None
        with self._lock:
            s = self._sessions.get(token)
            if s is not None and s.expires < time.time():
                del self._sessions[token]
                return None
            return s

    def end(self, token: str | None) -> None:
        with self._lock:
            self._sessions.pop(token or "", None)

    def current(self, token: str | None, key_dir: Path) -> Session | None:
        """The session of ``token`` with its key looked up again in ``key_dir``: None (and the
        session ended) if the key was revoked; the role as the key directory says now."""
        s = self.get(token)
        if s is None:
            return None
        found = role_of_public_key(s.public_key, key_dir)
        if found is None:
            self.end(token)
            return None
        if found[1] != s.role:
            s = Session(s.name, found[1], s.expires, s.public_key)
            with self._lock:
                if token in self._sessions:
                    self._sessions[token or ""] = s
        return s
