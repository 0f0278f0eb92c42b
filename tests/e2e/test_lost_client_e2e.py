"""A lost client never leaves the rig driven (issue 38, 7): real processes, real signals.

`sfdrig structure` holds the shaker at -40 N at a question when its terminal hangs up (the pty's
master closed: the kernel's SIGHUP), when it gets SIGTERM, or when it is killed (SIGKILL: the
daemon's operator lease lapses). Each time the drive ramps to 0 V within a bound of the signal,
the run is closed "aborted" with what happened, `sfdrig status` says so and the daemon is idle.
An abort typed while no question is asked is sent. A sweep's follower lost (SIGHUP) leaves the
sweep running to its plan. The page (`sfdrig web`) keeps the lease of a test it started while an
operator's page is open, and loses it when the page closes or the web server is killed.

Synchronisation: the terminal's prompts (pexpect), the daemon's live events (a subscriber) and
status replies; never sleeps. The bounds are wall time from the signal to the run's closing
event, stamped in the run file.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from datetime import datetime
from typing import Any

import numpy as np
import pexpect
import pytest

from control.run.programs.stream import FAULT_RAMP_S
from control.wire.client import CommandClient, Subscriber
from storage import open_run
from tests.e2e import test_web_e2e
from tests.e2e.conftest import REPO_ROOT, DaemonProcess, start_daemon
from tests.e2e.test_structure_operator_e2e import Terminal

# paced: the bounds are wall time (the abort within 2 s of a signal, the operator's 4 s lease)
pytestmark = [pytest.mark.e2e, pytest.mark.paced]
# the fixtures of the page's tests: headless Chromium (one for the module), the web servers
chromium = test_web_e2e.chromium
browser = test_web_e2e.browser
web_factory = test_web_e2e.web_factory

LEASE_S = 4.0  # the daemons' operator lease here (`sfdrig daemon --operator-lease-s`)
# from the signal to the drive at 0 V when the client sends the abort itself: the abort's round
# trip, a block, the 40 ms fade and closing the file, on a loaded PC
SIGNAL_BOUND_S = 2.0
# when nothing is sent (SIGKILL, a closed page): the lease, the command loop's beat (0.25 s), and
# the same as above
LEASE_BOUND_S = LEASE_S + 0.25 + SIGNAL_BOUND_S
WHERE = "static step 1 (x, -40 N, pass 1)"  # the run's reason: what it was doing (steps from 1)
HOLD = ["--set", 'static.axes=["x"]', "--set", "static.forces_n=[-40.0]",
        "--set", "static.repeats=1"]


@pytest.fixture(scope="module")
def lease_daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DaemonProcess]:
    """One daemon (`LEASE_S` operator lease) for the module: each test leaves it idle, and a
    daemon's start is seconds of a loaded machine's time."""
    runs = tmp_path_factory.mktemp("lost_client") / "runs"
    d = start_daemon(runs, "--operator-lease-s", f"{LEASE_S:g}")
    try:
        yield d
    finally:
        d.terminate()
        d.proc.communicate(timeout=10)
        err = (runs.parent / f"{runs.name}.stderr").read_text()
        if err:
            print(f"--- daemon stderr ---\n{err}")


@pytest.fixture
def daemon(lease_daemon: DaemonProcess) -> DaemonProcess:
    """The module's daemon, idle: what a failed test left running is aborted first (and its
    end waited for on the daemon's status heartbeats)."""
    d = lease_daemon
    with CommandClient(d.command) as c:
        if c.status()["state"] == "idle":
            return d
        with Subscriber(d.data, topics=["status"]) as beats:
            beats.wait_connected()
            c.abort("the previous test left a run going")
            deadline = time.monotonic() + 30.0
            while (st := beats.recv(timeout_s=1.0)) is None or \
                    st.header["status"]["state"] != "idle":
                assert time.monotonic() < deadline, "the daemon did not get back to idle"
    return d


def _holding(d: DaemonProcess, *extra: str) -> Terminal:
    """`sfdrig structure` at the static test's question at -40 N (the shaker holds it)."""
    t = Terminal(d.command, "--only", "static", *HOLD, "--runs-dir", str(d.runs_dir), *extra)
    where, _ = t.next()
    assert where == "static setup"
    t.type("")
    where, text = t.next()
    assert where == "static x -40 N pass 1, point 1/1" and "accept this point?" in text
    return t


def _run_end(sub: Subscriber, timeout_s: float = 60.0) -> tuple[str, str]:
    """(run id, "status: reason") of the next run's closing event on the live stream."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = sub.recv(timeout_s=1.0)
        if msg is None or msg.topic != "event" or msg.header["kind"] != "state":
            continue
        m = re.match(r"run (\S+) (completed|aborted|failed)(.*)$", msg.header["message"])
        if m:
            return m.group(1), m.group(2) + m.group(3)
    raise AssertionError(f"no run ended within {timeout_s:g} s")


def _stamp(iso: str) -> float:
    return datetime.fromisoformat(iso).timestamp()


def _check_ramped_down(d: DaemonProcess, run_id: str, signalled_at: float, within_s: float,
                       reason: str) -> float:
    """The run file: the shaker held -40 N until the abort, ramped to 0 V within the fade, and
    the programme ended within ``within_s`` of the signal; the status names the reason. Returns
    the seconds from the signal to the end."""
    with open_run(d.runs_dir / f"{run_id}.h5") as r:
        assert r.attrs["status"] == "aborted"
        assert reason in r.attrs["status_reason"], r.attrs["status_reason"]
        events = r.events
        fs = r.sample_rate_hz
        drive = r.channel("shaker_x")
        fx = r.channel("fx")
    (abort,) = [e for e in events if e["kind"] == "abort"]
    (ended,) = [e for e in events if e["message"] == "static programme aborted"]
    assert reason in abort["message"]
    # held: the load cell read the -40 N asked over the last 0.1 s before the abort
    held = fx[abort["sample"] - int(0.1 * fs):abort["sample"]]
    assert np.mean(held) == pytest.approx(-40.0, abs=4.0)
    # then 0 V: within the fade and the two blocks queued ahead (100 samples each)
    moving = np.flatnonzero(drive != 0.0)
    last_driven = int(moving[-1]) if moving.size else -1
    assert (last_driven - abort["sample"]) / fs <= FAULT_RAMP_S + 3 * 100 / fs
    assert np.all(drive[last_driven + 1:] == 0.0) and len(drive) - last_driven > 100
    took = _stamp(ended["time"]) - signalled_at
    assert 0.0 <= took <= within_s, took
    with CommandClient(d.command) as c:
        st = c.status()
    assert st["state"] == "idle" and st["question"] is None and st["operator_lease"] is None
    assert st["last_run"]["run_id"] == run_id and st["last_run"]["status"] == "aborted"
    assert reason in st["last_run"]["reason"]
    return took


def _status_text(d: DaemonProcess) -> str:
    out = subprocess.run([sys.executable, "-m", "sfdrig", "status", "--runs-dir",
                          str(d.runs_dir)], cwd=REPO_ROOT, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout


def _lose_the_terminal(d: DaemonProcess, lose: Any) -> tuple[DaemonProcess, Terminal, str, str,
                                                              float]:
    """`sfdrig structure` holding -40 N, then ``lose(terminal, daemon)``: (daemon, terminal, run id,
    the run's end "status: reason", when the signal came)."""
    with Subscriber(d.data, topics=["event", "status"]) as sub:
        sub.wait_connected()
        t = _holding(d)
        signalled_at = time.time()
        lose(t, d)
        run_id, end = _run_end(sub)
    return d, t, run_id, end, signalled_at


def _hang_up(t: Terminal, d: DaemonProcess) -> None:
    """Close the pty's master, as a terminal window closing does: the kernel sends SIGHUP."""
    t.child.ptyproc.fileobj.close()
    t.child.ptyproc.wait()
    t.child.ptyproc.closed = True


def _kill(sig: int) -> Any:
    def lose(t: Terminal, d: DaemonProcess) -> None:
        t.child.kill(sig)
        t.child.expect(pexpect.EOF)
        t.out = t.child.before
        t.child.close()
    return lose


def test_a_hung_up_terminal_aborts_the_held_static_test(daemon) -> None:
    d, t, run_id, end, signalled_at = _lose_the_terminal(daemon, _hang_up)
    assert t.child.ptyproc.exitstatus == 128 + signal.SIGHUP  # its own exit, after the abort
    reason = "the operator's terminal hung up (SIGHUP) in `sfdrig structure` (static)"
    assert end.startswith(f"aborted: {WHERE}: {reason}")
    took = _check_ramped_down(d, run_id, signalled_at, SIGNAL_BOUND_S, reason)
    print(f"SIGHUP: the drive at 0 V and the run closed {took:.3f} s after the hang-up")
    assert f"last run   {run_id}: aborted ({WHERE}: {reason})" in _status_text(d)


def test_sigterm_to_the_terminal_aborts_the_held_static_test(daemon) -> None:
    d, t, run_id, _, signalled_at = _lose_the_terminal(daemon, _kill(signal.SIGTERM))
    assert t.child.exitstatus == 128 + signal.SIGTERM and "Traceback" not in t.out
    assert "static: abort sent (drives ramp to zero)" in t.out
    took = _check_ramped_down(d, run_id, signalled_at, SIGNAL_BOUND_S,
                              "the client was told to end (SIGTERM) in `sfdrig structure` "
                              "(static)")
    print(f"SIGTERM: the drive at 0 V and the run closed {took:.3f} s after the signal")


def test_a_killed_terminal_loses_its_lease_and_the_test_is_aborted(daemon) -> None:
    def renewed_then_killed(t: Terminal, d: DaemonProcess) -> None:
        with CommandClient(d.command) as c:
            lease = c.status()["operator_lease"]
        assert lease["lease_s"] == LEASE_S and lease["silent_s"] < LEASE_S * 0.5  # renewed
        assert re.search(r"\noperator   last heard \d\.\d s ago \(the test is aborted after "
                         r"4 s without\)\n", _status_text(d))
        _kill(signal.SIGKILL)(t, d)  # nothing can be sent: only the lease tells

    d, t, run_id, end, signalled_at = _lose_the_terminal(daemon, renewed_then_killed)
    assert t.child.signalstatus == signal.SIGKILL
    assert re.match(re.escape(f"aborted: {WHERE}: operator lost: no heartbeat for ")
                    + r"4\.\d s \(the lease is 4 s", end), end
    took = _check_ramped_down(d, run_id, signalled_at, LEASE_BOUND_S,
                              "operator lost: no heartbeat for")
    # not before the lease: the last renewal came at most a quarter lease before the kill
    assert took >= LEASE_S * 0.75 - 0.1, took
    print(f"SIGKILL: the drive at 0 V and the run closed {took:.3f} s after the kill "
          f"(lease {LEASE_S:g} s)")
    assert f"aborted ({WHERE}: operator lost: no heartbeat for 4." in _status_text(d)


def test_an_abort_typed_between_two_questions_is_sent(daemon) -> None:
    """Between the setup and the first point (the shaker settling at -40 N for a long settle:
    no question pending), `a` aborts; it used to print "(nothing is asked now)" and drop it."""
    d = daemon
    t = Terminal(d.command, "--only", "static", *HOLD, "--set", "static.settle_s=600",
                 "--runs-dir", str(d.runs_dir))
    where, _ = t.next()
    assert where == "static setup"
    with Subscriber(d.data, topics=["block"]) as sub, CommandClient(d.command) as c:
        sub.wait_connected()
        t.type("")
        while (msg := sub.recv(timeout_s=30)) is not None and np.min(msg.row("fx")) > -20.0:
            pass  # blocks, not sleeps: the shaker is loading the housing toward -40 N
        assert msg is not None, "the shaker never loaded the housing"
        assert c.status()["question"] is None  # settling 600 s: nothing is asked
        typed_at = time.time()
        t.type("a")
        t.child.expect(r"  = abort sent \(drives ramp to zero\)")
        status, reason, path, code, rest = t.finish()
        st = c.status()
    assert status == "aborted" and code == 1 and "Traceback" not in rest
    assert "the operator typed abort at the terminal" in reason
    assert st["state"] == "idle" and st["last_run"]["status"] == "aborted"
    with open_run(d.runs_dir / path.name) as r:
        assert r.attrs["status"] == "aborted" and r.steps == []
        drive = r.channel("shaker_x")
        (ended,) = [e for e in r.events if e["message"] == "static programme aborted"]
    assert np.min(drive) < -0.01 and np.all(drive[-100:] == 0.0)  # it was loading, now 0 V
    took = _stamp(ended["time"]) - typed_at
    assert took <= SIGNAL_BOUND_S, took
    print(f"'a' between questions: the drive at 0 V and the run closed {took:.3f} s later")


def test_a_sweep_runs_on_when_its_follower_hangs_up(daemon) -> None:
    """A sweep is a batch job under the daemon's own limits: its follower's terminal hanging up
    ends the following (exit 129, no traceback), and the sweep runs to its last step (no
    operator lease holds it: the daemon's lease is `LEASE_S`)."""
    d = daemon
    freqs = [70.0, 80.0, 90.0, 100.0, 110.0, 120.0]  # about 14 s of rig time
    follower = pexpect.spawn(
        sys.executable, ["-m", "sfdrig", "sweep", "--set", "motion='x'", "--set",
                         "load_n=[40.0]", "--set", f"freq_hz={freqs}", "--set",
                         "settle_cycles=20", "--set", "record_cycles=200",
                         "--runs-dir", str(d.runs_dir)],
        cwd=str(REPO_ROOT), encoding="utf-8", timeout=120, dimensions=(50, 400))
    follower.expect(r"run (\S+) started: ")
    run_id = follower.match.group(1)
    with Subscriber(d.data, topics=["event", "status"]) as sub:
        sub.wait_connected()
        follower.ptyproc.fileobj.close()  # hang up
        follower.ptyproc.wait()
        follower.ptyproc.closed = True
        with CommandClient(d.command) as c:
            st = c.status()
        assert st["run_id"] == run_id and st["state"] == "running"  # on after its follower
        ended, end = _run_end(sub, timeout_s=300)
    assert follower.ptyproc.exitstatus == 128 + signal.SIGHUP
    assert ended == run_id and end == "completed", end
    with open_run(d.runs_dir / f"{run_id}.h5") as r:
        assert r.attrs["status"] == "completed" and len(r.steps) == len(freqs)
        assert np.all(r.channel("shaker_x")[-100:] == 0.0)


# --- the page --------------------------------------------------------------------------------
def _page_holding(browser: Any, url: str) -> tuple[Any, str]:
    """The page started the static test and answered its setup: the shaker holds a load at a
    point's question. Returns (the page, the run id)."""
    page, run_id = test_web_e2e.start_test_on_page(browser, url, "static")
    assert page.inner_text("#q-where") == "static setup"
    page.click("#q-ok")
    page.wait_for_function("document.getElementById('q-prompt').textContent.includes("
                           "'accept this point?')", timeout=60_000)
    return page, run_id


def _page_ramped_down(d: DaemonProcess, run_id: str, lost_at: float) -> float:
    with open_run(d.runs_dir / f"{run_id}.h5") as r:
        assert r.attrs["status"] == "aborted"
        assert "operator lost: no heartbeat for" in r.attrs["status_reason"]
        drive = r.channel("shaker_x")
        (ended,) = [e for e in r.events if e["message"] == "static programme aborted"]
    assert np.min(drive) < -0.01 and np.all(drive[-100:] == 0.0)
    took = _stamp(ended["time"]) - lost_at
    assert LEASE_S * 0.75 - 0.1 <= took <= LEASE_BOUND_S, took
    return took


def test_the_page_holds_its_test_while_open_and_loses_it_when_closed(daemon, web_factory,
                                                                      browser) -> None:
    d = daemon
    with Subscriber(d.data, topics=["event", "status"]) as sub:
        sub.wait_connected()
        page, run_id = _page_holding(browser, web_factory(d))
        # open for one and a half leases: the server renews it, the test waits for its answer
        with Subscriber(d.data, topics=["status"]) as beats, CommandClient(d.command) as c:
            beats.wait_connected()
            first = time.monotonic()
            while time.monotonic() - first < 1.5 * LEASE_S:
                st = beats.recv(timeout_s=1.0)
                if st is not None:  # the daemon's heartbeats, 4 a second
                    assert st.header["status"]["run_id"] == run_id
                    assert st.header["status"]["operator_lease"]["silent_s"] < LEASE_S
            assert c.status()["question"]["where"].startswith("static x -80 N")
        closed_at = time.time()
        page.close()  # the operator's only page: nobody renews now
        ended, end = _run_end(sub)
    assert ended == run_id and "operator lost: no heartbeat for" in end
    took = _page_ramped_down(d, run_id, closed_at)
    print(f"page closed: the drive at 0 V and the run closed {took:.3f} s later")


def test_a_killed_web_server_loses_the_pages_test(daemon, browser) -> None:
    d = daemon
    web = subprocess.Popen(
        [sys.executable, "-m", "sfdrig", "web", "--port", "0", "--command-endpoint", d.command,
         "--data-endpoint", d.data], cwd=REPO_ROOT, stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        url = web.stdout.readline().strip()  # type: ignore[union-attr]
        assert url.startswith("url="), url
        with Subscriber(d.data, topics=["event", "status"]) as sub:
            sub.wait_connected()
            page, run_id = _page_holding(browser, url[4:])
            killed_at = time.time()
            web.kill()  # SIGKILL: the page stays open, nobody renews the lease
            assert web.wait(30) == -signal.SIGKILL
            ended, end = _run_end(sub)
        assert ended == run_id and "operator lost: no heartbeat for" in end
        took = _page_ramped_down(d, run_id, killed_at)
        print(f"web server killed: the drive at 0 V and the run closed {took:.3f} s later")
        page.close()
    finally:
        if web.poll() is None:
            web.kill()
            web.wait(30)
        web.stdout.close()  # type: ignore[union-attr]
