"""The web process's link to the daemon: one subscriber thread and one command client.

The web process is a client like any other: it subscribes to the daemon's (or a proxy's) PUB
stream with `control.client.Subscriber` and sends commands with `control.client.CommandClient`.
The acquisition thread never knows it is there; if the web process falls behind, it loses
messages at its own high-water mark (counted, shown on the page), never the daemon.
"""

from __future__ import annotations

import threading
from typing import Any

from control.client import CommandClient, CommandRefused, DaemonUnavailable, Subscriber
from control.security import ClientKeys
from web.view import LiveView


class DaemonLink:
    """Feeds a `LiveView` from the daemon and forwards commands to it.

    Parameters
    ----------
    command_endpoint, data_endpoint : str
        The daemon's command socket; its data socket (or a proxy's).
    view : LiveView
    keys : ClientKeys, optional
        CURVE keys when the daemon requires them (the web process's own client key).
    timeout_s : float
        Command reply timeout [s].
    """

    def __init__(self, command_endpoint: str, data_endpoint: str, view: LiveView,
                 keys: ClientKeys | None = None, timeout_s: float = 5.0) -> None:
        self.command_endpoint = command_endpoint
        self.data_endpoint = data_endpoint
        self.view = view
        self.keys = keys
        self.timeout_s = timeout_s
        self._cmd_lock = threading.Lock()  # one DEALER socket, used by one thread at a time
        self._client = CommandClient(command_endpoint, timeout_s=timeout_s, keys=keys)
        self._stop = threading.Event()
        self._sub = Subscriber(data_endpoint, rcvhwm=2000, keys=keys)
        self._thread = threading.Thread(target=self._loop, name="sfdrig-web-feed", daemon=True)

    def start(self, timeout_s: float = 10.0) -> None:
        """Wait for the subscription to be live, take the status (late join), start the thread."""
        self._sub.wait_connected(timeout_s)
        with self._cmd_lock:
            self.view.set_status(self._client.status())
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.is_set():
            msg = self._sub.recv(timeout_s=0.2)
            if msg is not None:
                self.view.on_message(msg)
                if msg.topic in ("block", "status"):
                    self.view.set_lost(self._sub.lost)

    def command(self, cmd: str, **fields: Any) -> Any:
        """Send one command; return the reply (`CommandRefused`/`DaemonUnavailable` raise)."""
        with self._cmd_lock:
            return self._client.request(cmd, **fields)

    def try_command(self, cmd: str, **fields: Any) -> dict[str, Any]:
        """Send one command; a JSON-safe outcome ``{"ok", "error", "data"}`` for the page."""
        try:
            reply = self.command(cmd, **fields)
        except CommandRefused as err:
            return {"ok": False, "error": str(err), "data": {}}
        except DaemonUnavailable as err:
            return {"ok": False, "error": str(err), "data": {}}
        return {"ok": True, "error": "", "data": reply.data}

    @property
    def received(self) -> int:
        return self._sub.received

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)
        self._sub.close()
        with self._cmd_lock:
            self._client.close()
