"""The web process's link to the daemon: a feed thread, a watch thread and command clients.

The web process is a client like any other: it subscribes to the daemon's (or a proxy's) PUB
stream with `control.wire.client.Subscriber` and sends commands with
`control.wire.client.CommandClient`.
The acquisition thread never knows it is there; if the web process falls behind, it loses
messages at its own high-water mark (counted, shown on the page), never the daemon.

The page must never show a dead daemon as alive. The daemon sends a status heartbeat every
0.25 s; the watch thread judges the link every `WATCH_S`:

- heartbeats within `LOST_AFTER_S`: live;
- none for longer: the daemon's state file (when the web process found the daemon through one)
  is read again: a pid that is gone is lost at once; other endpoints than the ones followed (a
  daemon restarted on new ports) are followed from then on; otherwise the daemon is asked for
  its status (`PROBE_TIMEOUT_S`): an answer means the stream is late (the link stays up and
  the status is taken from the answer), none means lost.

The feed thread survives every message: one it cannot decode (a stranger on the socket, two
frames instead of three, bad JSON) is counted and shown, never the end of the feed.
"""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path
from typing import Any

from control.wire.client import (
    CommandClient,
    CommandRefused,
    DaemonUnavailable,
    Subscriber,
    process_gone,
)
from control.wire.protocol import Reply
from control.wire.security import ClientKeys
from web.view import LiveView

log = logging.getLogger(__name__)
LOST_AFTER_S = 1.0  # four missed heartbeats
WATCH_S = 0.2  # how often the link is judged
PROBE_TIMEOUT_S = 0.5  # a status poll's reply timeout


class DaemonLink:
    """Feeds a `LiveView` from the daemon, forwards commands, and follows the daemon's life.

    Parameters
    ----------
    command_endpoint, data_endpoint : str
        The daemon's command socket; its data socket (or a proxy's).
    view : LiveView
    keys : ClientKeys, optional
        CURVE keys when the daemon requires them (the web process's own client key).
    timeout_s : float
        Command reply timeout [s].
    state_file : Path, optional
        The daemon's ``RUNS_DIR/daemon.json`` when the endpoints came from it: read again while
        the link is down, so a daemon restarted (on any ports) is found again.
    """

    def __init__(self, command_endpoint: str, data_endpoint: str, view: LiveView,
                 keys: ClientKeys | None = None, timeout_s: float = 5.0,
                 state_file: Path | None = None) -> None:
        self.command_endpoint = command_endpoint
        self.data_endpoint = data_endpoint
        self.view = view
        self.keys = keys
        self.timeout_s = timeout_s
        self.state_file = state_file
        self.malformed = 0  # messages the feed could not use (counted, shown, skipped)
        self.reconnects = 0
        self._pid: int | None = None
        self._cmd_lock = threading.Lock()  # one DEALER socket, used by one thread at a time
        self._client = CommandClient(command_endpoint, timeout_s=timeout_s, keys=keys)
        self._probe = CommandClient(command_endpoint, timeout_s=PROBE_TIMEOUT_S, keys=keys)
        self._stop = threading.Event()
        self._sub = Subscriber(data_endpoint, rcvhwm=2000, keys=keys)
        self._follow: tuple[str, str] | None = None  # endpoints the feed thread is to switch to
        self._sub_lock = threading.Lock()
        self._thread = threading.Thread(target=self._loop, name="sfdrig-web-feed", daemon=True)
        self._watcher = threading.Thread(target=self._watch, name="sfdrig-web-watch",
                                         daemon=True)
        if state_file is not None:
            self._pid = self._read_state().get("pid")
        self._report("connecting", f"waiting for the first heartbeat from {data_endpoint}")

    def start(self, timeout_s: float = 10.0) -> None:
        """Wait for the subscription to be live, take the status (late join), start the threads."""
        self._sub.wait_connected(timeout_s)
        self.view.note_heartbeat()
        with self._cmd_lock:
            self.view.set_status(self._client.status())
        self._report("live", "")
        self._thread.start()
        self._watcher.start()

    # --- the feed thread ------------------------------------------------------------------
    def _loop(self) -> None:
        while not self._stop.is_set():
            with self._sub_lock:
                follow, self._follow = self._follow, None
            if follow is not None:
                self._switch_subscription(*follow)
            try:
                msg = self._sub.recv(timeout_s=0.1)
                if msg is None:
                    continue
                self.view.on_message(msg)
            except Exception as err:  # noqa: BLE001 - no message may end the feed
                self.malformed += 1
                self.view.note_malformed(self.malformed, f"{type(err).__name__}: {err}")
                if self.malformed <= 10 or self.malformed % 1000 == 0:
                    log.warning("skipped a message the feed cannot use (%d so far): %s",
                                self.malformed, err)
                continue
            if msg.topic in ("block", "status"):
                self.view.set_lost(self._sub.lost)

    def _switch_subscription(self, command: str, data: str) -> None:
        self._sub.close()
        self._sub = Subscriber(data, rcvhwm=2000, keys=self.keys)
        log.warning("following the daemon at %s (data %s)", command, data)

    # --- the watch thread -----------------------------------------------------------------
    def _watch(self) -> None:
        while not self._stop.wait(WATCH_S):
            try:
                self._judge()
            except Exception:  # noqa: BLE001 - the watch must go on; the page shows the link
                log.exception("judging the link to the daemon failed")

    def _judge(self) -> None:
        age = self.view.heartbeat_age()
        if age is not None and age <= LOST_AFTER_S:
            self._report("live", "")
            return
        silent = "no heartbeat yet" if age is None else f"no heartbeat for {age:.1f} s"
        if self.state_file is not None:
            state = self._read_state()
            if not state:
                self._report("lost", f"{silent}; no daemon state file {self.state_file} "
                                     "(the daemon stopped): waiting for one")
                return
            command, data, pid = state.get("command"), state.get("data"), state.get("pid")
            if process_gone(pid):
                self._report("lost", f"{silent}; the daemon (pid {pid}) is not running: waiting "
                                     f"for a new one in {self.state_file}")
                return
            if (isinstance(command, str) and isinstance(data, str)
                    and (command, data) != (self.command_endpoint, self.data_endpoint)):
                self._reconnect(command, data, pid)
                self._report("reconnecting", f"a new daemon (pid {pid}) at {command}: waiting "
                                             "for its heartbeat")
                return
        try:
            status = self._probe.status()
        except (DaemonUnavailable, CommandRefused) as err:
            self._report("lost", f"{silent}; no reply to status from {self.command_endpoint} "
                                 f"({err})")
            return
        self.view.set_status(status)
        self._report("late", f"{silent} on {self.data_endpoint}, but the daemon answers status")

    def _reconnect(self, command: str, data: str, pid: object) -> None:
        with self._cmd_lock:
            self._client.close()
            self._client = CommandClient(command, timeout_s=self.timeout_s, keys=self.keys)
        self._probe.close()
        self._probe = CommandClient(command, timeout_s=PROBE_TIMEOUT_S, keys=self.keys)
        with self._sub_lock:
            self._follow = (command, data)
        self.command_endpoint, self.data_endpoint = command, data
        self._pid = pid if isinstance(pid, int) else None
        self.reconnects += 1

    def _read_state(self) -> dict[str, Any]:
        """The state file's fields; {} if it is missing or being replaced."""
        assert self.state_file is not None
        try:
            state = json.loads(self.state_file.read_text())
        except (OSError, ValueError):
            return {}
        return state if isinstance(state, dict) else {}

    def _report(self, state: str, message: str) -> None:
        self.view.set_link({"state": state, "message": message,
                            "command": self.command_endpoint, "data": self.data_endpoint,
                            "pid": self._pid, "reconnects": self.reconnects})

    # --- commands -------------------------------------------------------------------------
    def command(self, cmd: str, **fields: Any) -> Reply:
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
        for t in (self._thread, self._watcher):
            if t.is_alive():
                t.join(5.0)
        self._sub.close()
        self._probe.close()
        with self._cmd_lock:
            self._client.close()

