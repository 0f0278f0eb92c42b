"""`sfdrig web` in a real browser (Debian's headless Chromium driven by Playwright) against a real
daemon process on the simulated rig, on random loopback ports.

Synchronisation: the web process's first stdout line names its URL; the page's own state
(``window.sfdrig``, the DOM) is waited on with Playwright's polling waits, never sleeps.
"""

from __future__ import annotations

import cmath
import math
import os
import selectors
import signal
import subprocess
import sys
import time
import tomllib
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from control.wire.client import CommandClient
from control.wire.security import make_keys
from control.wire.sweep_spec import field_units
from daq.config_files import to_toml
from storage.reader import open_run
from tests.ci import on_ci
from tests.e2e.conftest import REPO_ROOT, DaemonProcess, start_daemon

pytestmark = pytest.mark.e2e

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync"]
# Long enough in fast mode to act while it runs: 40 N dry X above the 45 Hz resonance, where it
# moves 10-40 um (below it 40 N moves the 0.79 MN/m rods about 50 um, at the 63.5 um limit).
LONG_SWEEP = """
motion = "x"
load_n = [40.0]
freq_hz = [70.0, 80.0, 90.0, 100.0, 110.0, 120.0, 130.0, 140.0, 150.0]
settle_cycles = 20
record_cycles = 400
"""
LONG_SWEEP = LONG_SWEEP.replace("150.0]", "150.0" + ", 150.0" * 30 + "]")  # never ends first
# A value of every number field of a sweep (both target kinds and both frequency forms: the form
# shows what it is given; the model refuses the mix when checked), none of them its default
EVERY_NUMBER: dict[str, Any] = {
    "amplitude_m": [13e-6, 25.5e-6], "load_n": [40.0], "ellipse_ratio": 0.7,
    "ellipse_phase_deg": -45.0, "freq_hz": [20.0, 35.5], "freq_start_hz": 20.0,
    "freq_stop_hz": 60.0, "freq_step_hz": 10.0, "freq_points": 5, "settle_cycles": 12,
    "record_cycles": 50, "tolerance_amplitude_pct": 2.5, "tolerance_phase_deg": 1.5,
    "max_updates": 6,
    "control": {"window_cycles": 3, "wait_cycles": 1, "min_ramp_s": 0.05,
                "settle_tolerance_pct": 0.5, "max_settle_cycles": 200,
                "initial_stiffness_n_per_m": 2.5e6, "aim_fraction": 0.4, "max_growth": 3.0,
                "breakaway_growth": 0.2, "start_growth": 0.3, "nominal_mass_kg": 10.5,
                "lubricated_added_mass_kg": 7.5, "nominal_damping_ns_per_m": 400.0,
                "lubricated_damping_ns_per_m": 3000.0, "plant_uncertainty": 0.25,
                "proportional_gain": 0.8, "block_s": 0.005, "ahead_blocks": 2},
}


def _chromium() -> str:
    if not Path(CHROMIUM).exists():
        if on_ci():
            pytest.fail(f"{CHROMIUM} missing on CI: ./dev test installs the chromium package")
        pytest.skip(f"{CHROMIUM} is not installed (./dev test installs it when run as root)")
    return CHROMIUM


@pytest.fixture(scope="module")
def chromium() -> Iterator[Any]:
    """Headless Chromium, launched once for a module (seconds on a loaded machine)."""
    exe = _chromium()
    from playwright import sync_api  # a test dependency (pyproject): missing is a failure
    with sync_api.sync_playwright() as p:
        # Playwright gives every launch a fresh, empty profile directory of its own
        b = p.chromium.launch(executable_path=exe, args=CHROMIUM_FLAGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def browser(chromium: Any) -> Iterator[Any]:
    """The module's Chromium for one test: each page opens in a context of its own (`_open`),
    and every context the test opened is closed after it (no page of an earlier test left
    reconnecting to a server that is gone)."""
    yield chromium
    for context in chromium.contexts:
        context.close()


@pytest.fixture
def web_factory(tmp_path: Path) -> Iterator[Any]:
    started: list[subprocess.Popen[str]] = []

    def factory(d: DaemonProcess, *extra: str, follow: bool = False) -> str:
        """``follow``: find the daemon through its runs directory's daemon.json (as the README
        starts it), not through endpoints given by hand."""
        err = open(tmp_path / f"web{len(started)}.stderr", "w")  # noqa: SIM115
        where = ["--runs-dir", str(d.runs_dir)] if follow else [
            "--command-endpoint", d.command, "--data-endpoint", d.data]
        proc = subprocess.Popen(
            [sys.executable, "-m", "sfdrig", "web", "--port", "0", *where,
             "--examples", str(REPO_ROOT / "examples"), *extra],
            cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=err, text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"})
        err.close()
        started.append(proc)
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)  # type: ignore[arg-type]
        ready = sel.select(60)
        sel.close()
        line = proc.stdout.readline() if ready else ""  # type: ignore[union-attr]
        if not line.startswith("url="):
            proc.kill()
            proc.wait(10)
            raise RuntimeError(f"sfdrig web did not start: {line!r}\n"
                               f"{(tmp_path / f'web{len(started) - 1}.stderr').read_text()}")
        return line.strip()[4:]

    yield factory
    for proc in started:
        if proc.poll() is None:
            proc.terminate()
        assert proc.wait(30) == 0, "sfdrig web did not shut down cleanly on SIGTERM"
        proc.stdout.close()  # type: ignore[union-attr]
    for f in sorted(tmp_path.glob("web*.stderr")):
        if f.read_text():
            print(f"--- {f.name} ---\n{f.read_text()}")
    # nothing the page did may end in an unhandled exception in the server (aiohttp logs it
    # with its traceback and still answers)
    for f in sorted(tmp_path.glob("web*.stderr")):
        assert "Traceback" not in f.read_text(), f"{f.name}: an unhandled exception was logged"


def _open(browser: Any, url: str, csp: bool = False) -> Any:
    """A page of ``url`` in ``browser`` (a Browser: its own context; or a BrowserContext made
    with ``bypass_csp=True``). The page's content security policy forbids what Playwright's
    string waits need (eval), so tests bypass it, except with ``csp`` (then only waits on
    selectors, and the page's CSP violations are collected in ``page.csp``)."""
    page = browser.new_page(bypass_csp=not csp) if hasattr(browser, "contexts") \
        else browser.new_page()
    page.csp = []
    page.on("console", lambda m: page.csp.append(m.text)
            if "Content Security Policy" in m.text else None)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.errors = errors  # JavaScript errors of the page, checked by the tests
    return page


def _upload(page: Any, tmp_path: Path, name: str, text: str) -> str:
    f = tmp_path / name
    f.write_text(text)
    page.set_input_files("#upload", str(f))
    page.click("#start-upload")
    page.click("#confirm-yes")  # a start is confirmed first
    page.wait_for_function("document.getElementById('message').textContent.length > 0")
    msg = page.inner_text("#message")
    page.evaluate("document.getElementById('message').textContent = ''")
    return msg


# Each plot's axes as drawn: the label (a function of the plot: it follows what is plotted) and
# the tick labels uPlot drew on the canvas at its split values
AXES_JS = """() => Object.fromEntries(Object.entries(plots).map(([k, p]) => [k, p.u.axes.map(
    (a, i) => ({label: typeof a.label === 'function' ? a.label(p.u, i) : a.label,
                ticks: a._values, splits: a._splits}))]))"""
PREFIX = {"n": 1e-9, "u": 1e-6, "m": 1e-3, "": 1.0, "k": 1e3, "M": 1e6}
# the y axes plotted in SI with a prefixed unit: the time traces and the amplitude (um or N)
SI_AXES = {"force": "N", "disp": "m", "acc": "m/s²", "drive": "V", "amp": "m or N",
           "runAmp": "m or N"}


def _axes(page: Any) -> dict[str, list[dict[str, Any]]]:
    """Every plot's axes (but the harmonics' log axis: 1X-5X and decades), each checked to be
    readable: at least 3 labelled ticks, no two alike, each tick the split value it stands at in
    the unit its label names (an SI-prefixed unit on the traces: its ticks read 1 to 999)."""
    out = page.evaluate(AXES_JS)
    out.pop("harm", None)
    for key, axes in out.items():
        for i, a in enumerate(axes):
            ticks = [t for t in a["ticks"] or [] if t]
            assert len(ticks) >= 3 and len(set(ticks)) == len(ticks), (key, i, a)
            unit = a["label"].rsplit("[", 1)[1].rstrip("]")
            scale = 1.0
            if i == 1 and key in SI_AXES:
                base = next(u for u in SI_AXES[key].split(" or ") if unit.endswith(u))
                prefix = unit.removesuffix(base)
                scale = PREFIX[prefix]
                assert 1.0 <= max(abs(float(t)) for t in ticks) < 1000.0, (key, a)
            assert [float(t) * scale for t in a["ticks"]] == pytest.approx(
                a["splits"], rel=1e-9, abs=1e-12 * scale), (key, i, a)
    return out


def _cli_sweep(d: DaemonProcess, path: Path) -> str:
    out = subprocess.run([sys.executable, "-m", "sfdrig", "sweep", str(path), "--no-follow",
                          "--command-endpoint", d.command, "--data-endpoint", d.data],
                         cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 1
    return (out.stdout + out.stderr).strip()


def test_operator_sweeps_watches_and_aborts_from_the_page(daemon_factory, web_factory, browser,
                                                           tmp_path):
    d = daemon_factory()
    page = _open(browser, web_factory(d))
    page.wait_for_function("window.sfdrig.frames >= 2 && window.sfdrig.role === 'operator'")
    assert page.inner_text("#state") == "idle"
    assert page.inner_text("#board") == d.board == "simulated rig (in process)"
    assert page.is_visible("#abort") and not page.is_visible("#viewer-note")
    assert page.is_enabled("#pump-on") and page.is_disabled("#pump-off")  # idle, pump off

    # bad files: the page shows the CLI's own messages
    bad_toml = 'motion = "x"\nload_n = [40.0\n'
    shown = _upload(page, tmp_path, "bad.toml", bad_toml)
    cli = _cli_sweep(d, tmp_path / "bad.toml")
    assert shown.startswith("cannot read bad.toml: ")
    assert cli.endswith(shown.removeprefix("cannot read bad.toml"))  # same TOML error text
    shown = _upload(page, tmp_path, "neg.toml", 'motion = "x"\nload_n = [40.0]\nfreq_hz = [-5.0]\n')
    cli = _cli_sweep(d, tmp_path / "neg.toml")
    assert "freq_hz" in shown and cli == f"sweep: {shown}"
    assert page.get_attribute("#message", "class") == "error"
    assert page.inner_text("#state") == "idle" and not list(d.runs_dir.glob("*.h5"))

    shown = _upload(page, tmp_path, "long.toml", LONG_SWEEP)
    assert shown.startswith("start: ok (run ")
    run_id = shown.removeprefix("start: ok (run ").rstrip(")")
    # the step table and the orbit update while it runs
    page.wait_for_function("document.querySelectorAll('#steps tbody tr').length >= 2",
                           timeout=120_000)
    # the run holds the pump relay (the daemon refuses either switch): no pump button offered
    assert page.is_disabled("#pump-on") and page.is_disabled("#pump-off")
    first = page.evaluate("window.sfdrig.lastFrame.traces.last_sample")
    page.wait_for_function(f"window.sfdrig.lastFrame.traces.last_sample > {first} + 5000")
    assert int(page.get_attribute("#orbit", "data-points")) > 100
    # 40 N at 70-80 Hz on the dry rig: tens of um, inside the 63.5 um limit
    rmax = float(page.get_attribute("#orbit", "data-rmax-um"))
    assert 1.0 < rmax < 63.5
    # zoomed, the orbit fills the plot: its edge at 1.25 x the largest radius, not 140 um
    page.check("#orbit-zoom")
    rmax, scale = page.evaluate("[document.getElementById('orbit').dataset.rmaxUm, "
                                "document.getElementById('orbit').dataset.scaleUm].map(Number)")
    assert scale == pytest.approx(max(1.0, 1.25 * rmax), rel=1e-3) and scale < 80.0
    # the trip levels drawn on the forces (448 N) and the drives (9 V), with units on the axes
    trips = page.evaluate("""() => { const last = (u) => u.data.slice(-2).map((d) => d[0]);
        return [last(plots.force.u), last(plots.drive.u)]; }""")
    assert trips[0] == [448.0, -448.0] and trips[1] == [9.0, -9.0]
    # every axis readable: its quantity, the unit its ticks are in, and at least 3 ticks
    axes = _axes(page)
    assert axes["force"][0]["label"] == "time [ms]" and axes["force"][1]["label"] == "force [N]"
    assert axes["drive"][1]["label"] == "drive [V]"
    assert axes["disp"][1]["label"] == "displacement [um]"  # tens of um
    assert axes["amp"][1]["label"] == "amplitude [N]"  # the sweep holds 40 N (not "um or N")
    assert axes["acc"][1]["label"].startswith("acceleration [")
    # the displacement's trip (the orbit radius) on the displacement traces once they reach a
    # quarter of it, and in words always
    disp = page.evaluate("""() => [plots.disp.u.series.map((s) => s.label),
        document.getElementById('disp-info').textContent]""")
    peak = float(disp[1].split("largest here ")[1].split()[0])
    assert disp[1].startswith("trip at 63.5 um (orbit radius): largest here ") and peak > 0.5
    assert ("+ trip" in disp[0]) == (peak >= 0.25 * 63.5), disp
    assert page.inner_text("#state") == "running" and page.inner_text("#run-id") == run_id
    # each input's RMS, peak and how much of its range it uses: 40 N of the load cell's range
    fx = [c.inner_text() for c in page.query_selector_all("#levels tr[data-input='fx'] td")]
    assert fx[1] == "N" and 20.0 < float(fx[3]) < 45.0 and float(fx[3]) < float(fx[4])
    assert 0.0 < float(fx[5]) < 90.0
    rows = page.query_selector_all("#steps tbody tr")
    first_row = [c.inner_text() for c in rows[0].query_selector_all("td")]
    assert first_row[1] == "70.0" and first_row[3] == "40.00 N"
    assert abs(float(first_row[4].split()[0]) - 40.0) < 0.4  # within the 1 % band
    # the drive it took against the 9 V limit, and the dynamic stiffness F/X at each step: its
    # size is the step's load over its orbit, its phase the orbit's lag, and Im K > 0 (the dry
    # rig dissipates: at 40 N the seal's 26 N of friction rules)
    drive_info = page.inner_text("#drive-info")
    assert drive_info.startswith("largest drive ") and " of 9.0 V: headroom " in drive_info
    st = page.evaluate("window.sfdrig.lastFrame.steps[0]")
    k = complex(st["kx_re_mn_per_m"], st["kx_im_mn_per_m"])
    assert abs(k) == pytest.approx(st["fx_n"] / st["x_um"], rel=1e-9)
    assert math.degrees(cmath.phase(k)) == pytest.approx(-st["phase_deg"], abs=1e-6)
    assert k.imag > 0 and 0 < st["drive_v"] < 9.0
    page.wait_for_function("/^\\d+ (s|min)/.test(document.getElementById('time-left').textContent)",
                           timeout=10_000)
    # the run's peak orbit and load so far, and no contact (issue 21)
    peaks = page.inner_text("#peaks")
    assert peaks.startswith(f"run {run_id} (so far): peak orbit "), peaks
    assert "of the 63.5 um limit, peak load" in peaks
    assert peaks.endswith("no journal-housing contact")
    assert 1.0 < float(peaks.split("peak orbit ")[1].split()[0]) < 63.5

    page.click("#abort")
    page.wait_for_function(f"document.getElementById('run-id').textContent.includes("
                           f"'{run_id} aborted')", timeout=60_000)
    assert page.inner_text("#state") == "idle"
    assert "operator abort from sfdrig web" in page.inner_text("#events")
    # the trips, faults and aborts alone, and those exported as CSV
    page.select_option("#event-filter", "limit_trip,fault,abort,error")
    kinds = {li.get_attribute("class") for li in page.query_selector_all("#events li")}
    assert kinds == {"ev-abort"}, kinds
    with page.expect_download() as download:
        page.click("#events-export")
    lines = Path(download.value.path()).read_text().splitlines()
    assert lines[0] == "time_utc,kind,message,run_id"
    assert any('"abort","operator abort from sfdrig web"' in line for line in lines[1:])
    assert all(',"abort",' in line for line in lines[1:])
    # once it has ended: the daemon's summary of the whole run (every block counted)
    page.wait_for_function("document.getElementById('peaks').textContent.includes('of 448 N')",
                           timeout=10_000)
    peaks = page.inner_text("#peaks")
    assert peaks.startswith(f"run {run_id}: peak orbit ") and "(so far)" not in peaks, peaks
    assert peaks.endswith("no journal-housing contact")
    assert page.get_attribute("#peaks", "class") == ""
    assert page.errors == []

    with open_run(d.runs_dir / f"{run_id}.h5") as run:
        assert run.status == "aborted"
        assert run.attrs["status_reason"] == "operator abort from sfdrig web"
        assert 2 <= len(run.steps) < 42
        fs = run.sample_rate_hz
        abort_at = next(e["sample"] for e in run.events if e["kind"] == "abort")
        drive = run.channel("shaker_x")
        before = np.abs(drive[max(0, abort_at - int(0.05 * fs)):abort_at]).max()
        assert before > 0.1  # it was driving
        moving = np.flatnonzero(np.abs(drive) > 1e-3 * before)
        assert moving[-1] < abort_at + int(0.1 * fs)  # down to 0.1 % within 100 ms
        assert np.abs(drive[-int(0.01 * fs):]).max() < 1e-9  # and the run ends at zero


def test_a_viewer_sees_the_page_and_controls_nothing(daemon_factory, web_factory, browser,
                                                     tmp_path):
    keys = tmp_path / "keys"
    make_keys(keys, commanders=["operator", "web"], readers=["viewer"])
    d = daemon_factory("--keys", str(keys))
    url = web_factory(d, "--keys", str(keys), "--key-name", "web")

    page = _open(browser, url)
    assert page.url.endswith("/login")
    stranger = tmp_path / "stranger"
    make_keys(stranger, commanders=["mallory"], readers=[])
    page.set_input_files("#key", str(stranger / "clients" / "mallory.key_secret"))
    page.click("#login")
    # the form's POST navigates: wait for its answer, not for the click
    page.wait_for_function(
        "document.body.innerText.includes('login refused: this key is not authorised')")

    page.goto(url)
    page.set_input_files("#key", str(keys / "clients" / "viewer.key_secret"))
    page.click("#login")
    # the login page (no window.sfdrig) may still be shown when the wait starts
    page.wait_for_function(
        "window.sfdrig && window.sfdrig.frames >= 2 && window.sfdrig.role === 'viewer'")
    assert page.inner_text("#who") == "viewer (viewer)"
    assert not page.is_visible("#controls") and page.is_visible("#viewer-note")
    # the server refuses even a hand-made request from the viewer's session
    out = page.evaluate("""async () => {
        const r = await fetch('/api/start', {method: 'POST', body: JSON.stringify(
            {example: 'dry_circular.toml'}), headers: {'Content-Type': 'application/json'}});
        return [r.status, await r.text()];
    }""")
    assert out[0] == 403 and "viewers control nothing" in out[1]
    out = page.evaluate("""async () => (await fetch('/api/command', {method: 'POST',
        body: JSON.stringify({cmd: 'pump', on: true})})).status""")
    assert out == 403
    n = page.evaluate("window.sfdrig.frames")
    page.wait_for_function(f"window.sfdrig.frames >= {n + 2}")
    frame = page.evaluate("window.sfdrig.lastFrame.status")
    assert frame["state"] == "idle" and frame["pump_on"] is False
    assert not list(d.runs_dir.glob("*.h5"))

    # a second browser session, with its own cookie
    op = _open(browser.new_context(bypass_csp=True), url)
    op.set_input_files("#key", str(keys / "clients" / "operator.key_secret"))
    op.click("#login")
    op.wait_for_function("window.sfdrig && window.sfdrig.role === 'operator'")
    assert op.is_visible("#abort")
    op.click("#pump-on")
    assert op.inner_text("#confirm-text") == "Switch the oil pump ON?"
    op.click("#confirm-yes")
    op.wait_for_function("document.getElementById('pump').textContent === 'ON'")
    page.wait_for_function("document.getElementById('pump').textContent === 'ON'")

    # the viewer leaves the page, its key is revoked, and the address typed again: the login,
    # never a page kept by the browser that reconnects for ever
    page.goto("about:blank")
    (keys / "readers" / "viewer.key").unlink()
    page.goto(url)
    page.wait_for_selector("#key")
    assert page.url.endswith("/login")
    assert page.errors == []


def test_beyond_loopback_needs_keys_and_tls(tmp_path):
    base = [sys.executable, "-m", "sfdrig", "web", "--host", "0.0.0.0", "--command-endpoint",
            "tcp://127.0.0.1:1", "--data-endpoint", "tcp://127.0.0.1:2"]
    out = subprocess.run(base, cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "requires --keys DIR" in out.stderr
    assert "Traceback" not in out.stderr
    make_keys(tmp_path / "keys", commanders=["web"], readers=[])
    out = subprocess.run([*base, "--keys", str(tmp_path / "keys"), "--key-name", "web"],
                         cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "requires --tls-cert and --tls-key" in out.stderr


def test_no_daemon_is_one_line_not_a_traceback(tmp_path):
    out = subprocess.run([sys.executable, "-m", "sfdrig", "web", "--port", "0",
                          "--runs-dir", str(tmp_path)],
                         cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and out.stderr.startswith("web: no daemon state file")
    assert "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) == 1


def test_the_operator_answers_a_structure_test_in_the_page(daemon_factory, web_factory,
                                                            browser):
    """The same operator protocol as the terminal: the page shows the daemon's question, an
    entry with a wrong unit is refused with the daemon's reason, a right one is taken, a point is
    repeated, and the test is aborted half way from the question (pump off, run closed)."""
    d = daemon_factory()
    url = web_factory(d)
    page = _open(browser, url)
    viewer = _open(browser, web_factory(d, "--role", "viewer"))
    page.wait_for_function("window.sfdrig.frames >= 2 && window.sfdrig.role === 'operator'")
    page.select_option("#test-kind", "flow")
    page.click("#start-test")  # the flow test with its defaults: 8-25 kPa, two passes
    page.click("#confirm-yes")
    page.wait_for_function("document.getElementById('message').textContent.includes('run ')")
    run_id = page.inner_text("#message").removeprefix("start: ok (run ").rstrip(")")
    page.wait_for_selector("#question:not([hidden])", timeout=60_000)
    assert page.inner_text("#q-where") == "flow 8 kPa pass 1, point 1/10"
    assert "Set the supply pressure to 8 kPa" in page.inner_text("#q-prompt")
    assert page.inner_text("#q-shows") == "the simulated instrument shows: 8 kPa"
    assert page.is_visible("#q-entry") and page.inner_text("#q-unit") == "[kPa]"
    # a viewer sees the question, without a way to answer it
    viewer.wait_for_selector("#question:not([hidden])", timeout=60_000)
    assert not viewer.is_visible("#q-ok") and not viewer.is_visible("#q-abort")

    page.fill("#q-entry", "10 kg")
    page.click("#q-ok")
    page.wait_for_function("document.getElementById('message').textContent.includes('kg')")
    # the daemon's reason, the same line the terminal shows
    assert page.inner_text("#message") == ("answer refused (invalid): answer: supply pressure: "
                                           "'kg' is not a unit of pressure (use Pa, kPa, MPa, "
                                           "bar, psi)")
    assert page.get_attribute("#message", "class") == "error"
    page.fill("#q-entry", "8 kPa")
    page.press("#q-entry", "Enter")  # Enter in the field answers too
    page.wait_for_function("document.getElementById('q-where').textContent.startsWith("
                           "'flow 12 kPa')", timeout=60_000)
    first = page.inner_text("#q-id")  # read before the click: the new question can be
    page.click("#q-repeat")           # drawn before a read after the click returns
    page.wait_for_function(f"document.getElementById('q-id').textContent !== '{first}'",
                           timeout=60_000)
    assert page.inner_text("#q-where").startswith("flow 12 kPa pass 1, point 2/10")
    page.click("#q-abort")
    page.wait_for_function(f"document.getElementById('run-id').textContent.includes("
                           f"'{run_id} aborted')", timeout=60_000)
    assert not page.is_visible("#question") and page.inner_text("#pump") == "off"
    with open_run(d.runs_dir / f"{run_id}.h5") as r:
        assert r.attrs["status"] == "aborted" and len(r.steps) == 1
        assert r.steps[0]["supply_pressure_pa"] == 8e3
        assert r.attrs["operator"] == "local"  # who is logged in to the page
        ops = [e["message"] for e in r.events if e["kind"] == "operator"]
        assert np.all(r.channel("shaker_x")[-100:] == 0.0)
    assert any("refused entry '10 kg'" in m for m in ops)
    assert any(m.endswith("ok '8 kPa' = 8 kPa") for m in ops)
    assert page.errors == [] and viewer.errors == []


def start_test_on_page(browser: Any, url: str, kind: str) -> tuple[Any, str]:
    """An operator's page that started the structure test ``kind`` (the page's choice) and
    shows its first question; (the page, the run id)."""
    page = _open(browser, url)
    page.wait_for_function("window.sfdrig.frames >= 2 && window.sfdrig.role === 'operator'")
    page.select_option("#test-kind", kind)
    page.click("#start-test")
    page.click("#confirm-yes")
    page.wait_for_function("document.getElementById('message').textContent.includes('run ')")
    run_id = page.inner_text("#message").removeprefix("start: ok (run ").rstrip(")")
    page.wait_for_selector("#question:not([hidden])", timeout=60_000)
    return page, run_id


def test_the_page_starts_the_static_test_by_hand(daemon_factory, web_factory, browser):
    """The page offers the static test loaded by hand (report IV.1: the force gauge): its
    questions ask the operator to push, never to stand clear, and the shakers stay at 0 V."""
    d = daemon_factory()
    page, run_id = start_test_on_page(browser, web_factory(d), "static:hand")
    assert page.inner_text("#q-where") == "static setup"
    prompt = page.inner_text("#q-prompt")
    assert "you will push the housing" in prompt and "stand clear" not in prompt
    page.click("#q-ok")
    page.wait_for_function("document.getElementById('q-prompt').textContent.startsWith("
                           "'Push the housing along')", timeout=60_000)
    assert "by hand" in page.inner_text("#q-where")
    page.click("#q-abort")
    page.wait_for_function(f"document.getElementById('run-id').textContent.includes("
                           f"'{run_id} aborted')", timeout=60_000)
    with open_run(d.runs_dir / f"{run_id}.h5") as r:
        assert r.attrs["status"] == "aborted" and len(r.steps) == 0
        for drive in r.drive_names:
            assert np.all(r.channel(drive) == 0.0), drive  # by hand: the shakers never drive
    assert page.errors == []


def test_a_killed_daemon_looks_gone_and_a_restarted_one_is_found(daemon_factory, web_factory,
                                                                  browser):
    """Issue 25: kill -9 of the daemon mid-run used to leave "running", a moving sine and a
    counting "time left" for 30 s; a daemon restarted on new ports was never found. Now the page
    says LOST within 2 s, greys the plots with the time of the last data, offers no button,
    and finds the new daemon through runs/daemon.json by itself."""
    d = daemon_factory()
    url = web_factory(d, follow=True)
    page = _open(browser, url)
    strict = _open(browser, url, csp=True)  # the page under its own CSP: nothing blocked
    page.wait_for_function("window.sfdrig.frames >= 2 && window.sfdrig.role === 'operator'")
    assert page.inner_text("#link") == "live" and page.inner_text("#state") == "idle"
    with CommandClient(d.command) as c:
        run_id = c.start_sweep(tomllib.loads(LONG_SWEEP)).data["run_id"]
    page.wait_for_function("document.querySelectorAll('#steps tbody tr').length >= 1 && "
                           "/^\\d+ (s|min)/.test(document.getElementById('time-left')"
                           ".textContent)", timeout=120_000)
    assert page.inner_text("#state") == "running" and not page.is_disabled("#abort")
    assert page.is_disabled("#start-example") and page.inner_text("#data-age").endswith(" s old")
    # the history's row of the running run follows it: its steps as the step table's
    page.wait_for_function(f"(() => {{ const r = document.querySelector(\"#runs tbody tr"
                           f"[data-run='{run_id}']\"); return r !== null && r.cells[3].textContent"
                           " === String(document.querySelectorAll('#steps tbody tr').length); })()")
    assert not page.evaluate("document.body.classList.contains('stale')")

    t0 = time.monotonic()
    d.proc.kill()  # SIGKILL: no goodbye, daemon.json stays behind
    d.proc.wait(10)  # reaped, as the shell that started it would (a zombie's pid still answers)
    page.wait_for_function("document.getElementById('link').textContent === 'LOST'",
                           timeout=2_000)
    shown_after_s = time.monotonic() - t0
    print(f"LOST shown {shown_after_s:.2f} s after the kill")
    assert shown_after_s < 2.0
    assert page.inner_text("#state") == "unknown (was running)"
    assert page.inner_text("#run-id") == f"{run_id} (last known)"
    assert page.inner_text("#time-left") == "-" and page.inner_text("#step") == "-"
    banner = page.inner_text("#link-banner")
    assert banner.startswith("Daemon LOST: ") and "is not running" in banner, banner
    assert banner.endswith("Nothing below is live.")
    page.wait_for_function("document.body.classList.contains('stale')")
    assert page.inner_text("#data-age").startswith("none since ")
    assert page.is_visible(".panel .stale-note")
    assert page.inner_text(".panel .stale-note").startswith("not live: last data at ")
    assert page.inner_text("#harm-info").startswith("NOT live")
    for button in ("#abort", "#pause", "#resume", "#start-example", "#pump-on", "#pump-off"):
        assert page.is_disabled(button), button

    d2 = start_daemon(d.runs_dir)  # what `sfdrig daemon` does again: new random ports
    try:
        assert (d2.command, d2.data) != (d.command, d.data)
        page.wait_for_function("document.getElementById('link').textContent === 'live'",
                               timeout=30_000)
        page.wait_for_function("document.getElementById('state').textContent === 'idle'")
        assert not page.is_visible("#link-banner")
        assert not page.is_disabled("#start-example") and page.is_disabled("#abort")
        # the new daemon closed the killed run as interrupted, and the history lists it so
        with open_run(d.runs_dir / f"{run_id}.h5") as run:
            assert run.status == "interrupted"
            steps_in_file = len(run.steps)
        row = f"#runs tbody tr[data-run='{run_id}']"
        page.wait_for_function(f"(() => {{ const r = document.querySelector(\"{row}\"); "
                               "return r && r.cells[4].textContent === 'interrupted'; })()")
        assert page.inner_text(f"{row} td:nth-child(4)") == str(steps_in_file)
        page.click(f"{row} button")  # open it: its step table and plot from the file
        page.wait_for_selector("#run:not([hidden])")
        assert page.inner_text("#run-title") == f"{run_id} (sweep, interrupted)"
        rows = page.query_selector_all("#run-steps tbody tr")
        assert len(rows) == steps_in_file >= 1
        assert rows[0].query_selector_all("td")[1].inner_text() == "70.0"
        size = page.evaluate("""async () => (await (await fetch(
            document.getElementById('dl-h5').href)).arrayBuffer()).byteLength""")
        assert size == (d.runs_dir / f"{run_id}.h5").stat().st_size
        page.fill("#note-text", "daemon killed on purpose (issue 25 test)")
        page.click("#note-add")
        page.wait_for_function("document.getElementById('run-notes').children.length === 1")
        assert page.inner_text("#run-notes").endswith(
            "local: daemon killed on purpose (issue 25 test)")
        strict.wait_for_selector("#link.live")
        assert strict.csp == [] and page.errors == [] and strict.errors == []
    finally:
        assert d2.terminate() == 0
        d2.proc.communicate(timeout=10)


def _flat(spec: dict[str, Any]) -> dict[str, Any]:
    """A sweep's fields by dotted path (``control.block_s``)."""
    return {k: v for k, v in spec.items() if k != "control"} | {
        f"control.{k}": v for k, v in spec.get("control", {}).items()}


def test_a_sweep_defined_on_the_page(daemon_factory, web_factory, browser, tmp_path):
    """The form has every field of the sweep model; problems are shown at their field (the
    model's own messages), a rule between fields above the form; a valid sweep is summarised,
    saved as the TOML `sfdrig sweep` reads, loaded back, confirmed and started as given."""
    d = daemon_factory()
    page = _open(browser, web_factory(d))
    page.wait_for_function("window.sfdrig.frames >= 2 && window.sfdrig.formReady === true")
    page.click("#editor summary")
    fields = page.eval_on_selector_all("#sweep-form [data-field]", "els => els.map(e => "
                                       "e.dataset.field)")
    assert {"motion", "amplitude_m", "load_n", "freq_hz", "freq_start_hz", "freq_points",
            "tolerance_amplitude_pct", "on_not_converged", "control.window_cycles",
            "control.algorithm"} <= set(fields)
    assert len(fields) == 20 + 20  # SweepSpec's 20 fields and ControlSettings' 20

    # every number field in its unit: a file with a value of each loaded into the form shows
    # the field's unit beside it and the value in that unit (lengths in um: x 1e6), and the
    # form reads back the very numbers of the file
    (tmp_path / "every.toml").write_text(to_toml(EVERY_NUMBER))
    page.set_input_files("#sweep-load", str(tmp_path / "every.toml"))
    page.wait_for_function("document.querySelector(\"[data-field='control.block_s']\").value"
                           " === '0.005'")
    shown = {f: (v, u) for f, v, u in page.eval_on_selector_all(
        "#sweep-form [data-field]", "els => els.map(e => [e.dataset.field, e.value, "
        "e.nextElementSibling.textContent])")}  # the unit beside the input
    flat = _flat(EVERY_NUMBER)
    units = field_units()
    assert set(flat) == set(units)  # the file holds every number field
    for path, value in flat.items():
        unit, scale = ("um", 1e6) if units[path] == "m" else (units[path], 1.0)
        text, unit_text = shown[path]
        assert unit_text == (f"[{unit}]" if unit else ""), path
        values = value if isinstance(value, list) else [value]
        assert [float(t) for t in text.split(", ")] == pytest.approx(
            [v * scale for v in values], rel=1e-12), (path, text)
    assert shown["control.initial_stiffness_n_per_m"] == ("2500000", "[N/m]")
    assert shown["amplitude_m"] == ("13, 25.5", "[um]")
    back = _flat(page.evaluate("readForm()"))  # what Check would send
    assert {k: back[k] for k in flat} == flat
    page.click("#sweep-defaults")

    def error_at(field: str) -> str:
        return page.inner_text(f"#sweep-form [data-error-for='{field}']")

    page.fill("[data-field='load_n']", "40")
    page.fill("[data-field='freq_hz']", "70, -5")
    page.fill("[data-field='control.window_cycles']", "0")
    page.click("#sweep-check")
    page.wait_for_function("document.querySelector(\"[data-error-for='freq_hz']\")"
                           ".textContent.length > 0")
    assert error_at("freq_hz") == "Input should be greater than 0 (got -5)"
    assert error_at("control.window_cycles") == ("Input should be greater than or equal to 1 "
                                                 "(got 0)")
    assert page.is_disabled("#sweep-start")
    page.fill("[data-field='control.window_cycles']", "2")
    page.fill("[data-field='freq_hz']", "70, 80")
    page.fill("[data-field='amplitude_m']", "20")  # and load_n: one target kind only
    page.click("#sweep-check")
    page.wait_for_function("document.getElementById('sweep-form-error').textContent.length > 0")
    assert page.inner_text("#sweep-form-error") == ("give exactly one of amplitude_m (hold "
                                                    "displacement) or load_n (hold load)")
    page.fill("[data-field='amplitude_m']", "")
    page.fill("[data-field='settle_cycles']", "20")
    page.click("#sweep-check")
    page.wait_for_function("!document.getElementById('sweep-start').disabled")
    summary = page.inner_text("#sweep-summary").splitlines()
    assert summary[0] == "(no name): x, hold load at 40.00 N"
    assert summary[1] == "2 steps: 2 frequencies from 70.00 to 80.00 Hz"
    # (20 + 40) cycles at 70 and at 80 Hz: 0.857 + 0.75 = 1.6 s
    assert summary[2].startswith("settling and recording alone: 1.6 s")
    assert summary[3].startswith("pump: must be OFF")
    assert summary[5] == "limits: orbit 63.5 um, load 448 N, drive 9.0 V"

    with page.expect_download() as saved:
        page.click("#sweep-save")
    toml_text = Path(saved.value.path()).read_text()
    assert tomllib.loads(toml_text) == {"load_n": [40.0], "freq_hz": [70.0, 80.0],
                                        "settle_cycles": 20}
    page.click("#sweep-defaults")
    assert page.input_value("[data-field='load_n']") == ""
    (tmp_path / "saved.toml").write_text(toml_text)
    page.set_input_files("#sweep-load", str(tmp_path / "saved.toml"))
    page.wait_for_function("!document.getElementById('sweep-start').disabled")
    assert page.input_value("[data-field='freq_hz']") == "70, 80"
    assert page.input_value("[data-field='settle_cycles']") == "20"

    page.click("#sweep-start")
    assert page.inner_text("#confirm-text").startswith("Start: (no name): x, hold load at 40.00 N")
    page.click("#confirm-yes")
    page.wait_for_function("document.getElementById('message').textContent.includes('run ')")
    run_id = page.inner_text("#message").removeprefix("start: ok (run ").rstrip(")")
    page.wait_for_function(f"document.getElementById('run-id').textContent.includes("
                           f"'{run_id} completed')", timeout=120_000)
    with open_run(d.runs_dir / f"{run_id}.h5") as run:
        assert [s["freq_hz"] for s in run.steps] == [70.0, 80.0]
        assert run.test_spec["settle_cycles"] == 20 and run.test_spec["load_n"] == [40.0]
    assert page.errors == []


def test_the_transfer_and_its_coherence_live_and_from_history(daemon_factory, web_factory,
                                                              browser):
    """Issue 25 (deliverable 4): each step's X/F, F/X and coherence from the recorded samples,
    drawn against frequency while a sweep runs (the daemon's own run file, read again at each
    step) and for a run opened from the history, with a step of low coherence greyed and its
    value shown."""
    from tests.web.test_history import _write as write_history_run
    from tests.web.test_transfer import FREQS, NOISY_STEP, rig_k, write_rig_run

    d = daemon_factory()
    write_rig_run(d.runs_dir / "RIG.h5", "RIG")  # a linear rig's sweep, one noisy step
    # and a run that held displacement: 20 and 20.2 um at 20 and 30 Hz
    write_history_run(d.runs_dir / "DISP.h5", "DISP", "2026-11-25T10:00:00.000+00:00",
                      "completed", [20.0, 20.2], 1)
    page = _open(browser, web_factory(d, follow=True))
    page.wait_for_function("window.sfdrig.frames >= 2 && window.sfdrig.role === 'operator'")

    # live: the simulated rig's sweep; every step's point is computed from the samples
    with CommandClient(d.command) as c:
        run_id = c.start_sweep(tomllib.loads(LONG_SWEEP)).data["run_id"]
    page.wait_for_function(
        f"(() => {{ const p = document.getElementById('transfer-live'); "
        f"return p.dataset.run === '{run_id}' && Number(p.dataset.points) >= 3; }})()",
        timeout=120_000)
    # one snapshot (the table is redrawn at each step)
    steps, live = page.evaluate("""() => [window.sfdrig.lastFrame.steps,
        [...document.querySelectorAll('#transfer-live .transfer-table tbody tr')].map((tr) =>
            [tr.className, [...tr.cells].map((c) => c.textContent)])]""")
    assert page.inner_text("#state") == "running"
    print("live transfer rows:", live[:3], "controller's F/X:",
          [(s["kx_re_mn_per_m"], s["kx_im_mn_per_m"]) for s in steps[:3]])
    for cls, cells in live[:3]:
        i = int(cells[0]) - 1
        assert cells[2] == "x" and float(cells[1]) == steps[i]["freq_hz"]
        # the controller's own lock-in over the same record, the step table's F/X: the same
        # stiffness within 1 % (the page's is from the raw samples, segment by segment)
        k_page = complex(float(cells[5]), float(cells[6]))
        k_ctl = complex(steps[i]["kx_re_mn_per_m"], steps[i]["kx_im_mn_per_m"])
        assert abs(k_page - k_ctl) < 0.01 * abs(k_ctl), (cells, k_ctl)
        assert float(cells[7]) > 0.99 and cls != "low-coh"  # the simulated rig is clean
    page.click("#abort")
    page.wait_for_function("document.getElementById('state').textContent === 'idle'",
                           timeout=60_000)

    # from history, each run's amplitude axis in its own unit: um of displacement, N of load
    page.wait_for_selector("#runs tbody tr[data-run='DISP']")
    page.click("#runs tbody tr[data-run='DISP'] button")
    page.wait_for_function("document.getElementById('transfer-run').dataset.run === 'DISP'")
    amp = _axes(page)["runAmp"][1]
    assert amp["label"] == "amplitude [um]" and 19.0 < float(amp["ticks"][0]) < 21.0, amp
    # the linear rig's run, k - m w^2 + j c w, the noisy step greyed
    row = "#runs tbody tr[data-run='RIG']"
    page.wait_for_selector(row)
    page.click(f"{row} button")
    page.wait_for_function("document.getElementById('transfer-run').dataset.run === 'RIG'")
    axes = _axes(page)
    assert axes["runAmp"][1]["label"] == "amplitude [N]"
    assert axes["transfer-run-k"][1]["label"] == "F/X [MN/m]"
    rows = page.query_selector_all("#transfer-run .transfer-table tbody tr")
    assert len(rows) == len(FREQS)
    for i, tr in enumerate(rows):
        cells = [c.inner_text() for c in tr.query_selector_all("td")]
        k = complex(float(cells[5]), float(cells[6])) * 1e6
        if i == NOISY_STEP:
            assert tr.get_attribute("class") == "low-coh"
            assert 0.2 < float(cells[7]) < 0.8
        else:
            assert tr.get_attribute("class") != "low-coh" and float(cells[7]) > 0.999
            assert abs(k - rig_k(FREQS[i])) < 2e-3 * abs(rig_k(FREQS[i]))  # 4 digits shown
    info = page.inner_text("#transfer-run .transfer-info")
    coh = page.inner_text(f"#transfer-run .transfer-table tbody tr:nth-child({NOISY_STEP + 1})"
                          " td.coh")
    assert info == f"low coherence: {FREQS[NOISY_STEP]:.1f} Hz x: {float(coh):.2f}", info
    # the plots: the trusted points coloured, the low-coherence one only in the grey series
    grey = page.evaluate("""() => { const u = plots['transfer-run-coh'].u;
        return [u.series.map((s) => s.label), u.data]; }""")
    labels, data = grey
    assert labels[1:] == ["coherence x", "low coherence", "threshold"]
    assert [v is None for v in data[1]] == [i == NOISY_STEP for i in range(len(FREQS))]
    assert [v is not None for v in data[2]] == [i == NOISY_STEP for i in range(len(FREQS))]
    assert data[3] == [0.9] * len(FREQS)
    k_plot = page.evaluate("plots['transfer-run-k'].u.data")
    assert k_plot[0] == FREQS and k_plot[1][0] == pytest.approx(rig_k(FREQS[0]).real / 1e6,
                                                                 rel=1e-3)
    assert page.errors == []


def test_trips_and_e_stops_across_runs(daemon_factory, web_factory, browser):
    """Issue 25 (deliverable 4): the trips, e-stops, watchdogs and interrupted runs of the runs
    directory in one table, read from the run files (a killed daemon's run included), filtered
    by incident and date, exported as CSV, each run opened from its row."""
    from tests.web.test_trips import TRIP, write_incident_runs

    d = daemon_factory()
    write_incident_runs(d.runs_dir)  # a test day's earlier runs (25 Nov)
    page = _open(browser, web_factory(d, follow=True))
    page.wait_for_function("window.sfdrig.frames >= 2 && window.sfdrig.incidentsLoaded >= 1")
    page.wait_for_function("document.querySelectorAll('#incident-table tbody tr').length === 4")

    # a run of the daemon's own, killed with it (kill -9) and closed as interrupted by the
    # daemon started again
    with CommandClient(d.command) as c:
        run_id = c.start_sweep(tomllib.loads(LONG_SWEEP)).data["run_id"]
    page.wait_for_function("document.querySelectorAll('#steps tbody tr').length >= 2",
                           timeout=120_000)
    d.proc.kill()
    d.proc.wait(10)
    d2 = start_daemon(d.runs_dir)
    try:
        # (closed by the new daemon: its reason recorded)
        page.wait_for_function(f"(() => {{ const r = document.querySelector(\"#incident-table "
                               f"tbody tr[data-run='{run_id}']\"); return r !== null && r.cells[3]"
                               ".textContent.endsWith('recovered at the next daemon start'); })()",
                               timeout=60_000)
    finally:
        assert d2.terminate() == 0
        d2.proc.communicate(timeout=10)

    def rows() -> list[tuple[str, list[str]]]:
        return page.evaluate("""() => [...document.querySelectorAll('#incident-table tbody tr')]
            .map((tr) => [tr.className, [...tr.cells].map((c) => c.textContent)])""")

    table = rows()
    print("the incidents as the page shows them:", table)
    assert [r[1][1] for r in table] == [run_id, "I1", "W1", "E1", "T1"]  # newest first
    cls, mine = table[0]
    with open_run(d.runs_dir / f"{run_id}.h5") as run:
        assert run.status == "interrupted"
        reason, fs, n = run.attrs["status_reason"], run.sample_rate_hz, run.n_samples
        # the step whose record holds the last sample on disk, else the one after the last
        step = next((s["index"] for s in run.steps
                     if s["first_sample"] <= n - 1 < s["last_sample"]), len(run.steps))
        x = run.signal("x", max(0, n - int(fs)), n)
    assert cls == "inc-interrupted" and mine[2] == "interrupted" and mine[3] == reason
    # where: that step at its planned frequency (70, 80, ... Hz)
    planned = tomllib.loads(LONG_SWEEP)["freq_hz"]
    assert mine[4] == (f"step {step + 1}/{len(planned)} at {planned[step]:.1f} Hz, "
                       f"{(n - 1) / fs:.3f} s into the run")
    # the peak orbit of its last second (X only: y stays near 0 on this rig)
    assert abs(float(mine[5]) - np.abs(x).max() * 1e6) < 0.1 * np.abs(x).max() * 1e6 + 1.0
    assert [r[1][2] for r in table[1:]] == ["interrupted", "watchdog", "e-stop", "trip"]
    assert table[-1][1][3:7] == [TRIP, "step 3/3 at 70.0 Hz, 1.200 s into the run", "70.0",
                                 "310.0"]

    page.select_option("#incident-filter", "e-stop")
    page.wait_for_function("document.querySelectorAll('#incident-table tbody tr').length === 1")
    assert rows()[0][1][1:3] == ["E1", "e-stop"]
    page.select_option("#incident-filter", "trip,e-stop,watchdog")
    page.fill("#incident-since", "2026-11-25")
    page.dispatch_event("#incident-since", "change")
    page.wait_for_function("document.querySelectorAll('#incident-table tbody tr').length === 3")
    assert [r[1][1] for r in rows()] == ["W1", "E1", "T1"]
    with page.expect_download() as download:
        page.click("#incidents-export")
    lines = Path(download.value.path()).read_text().splitlines()
    assert lines[0].startswith('"time_utc","run_id","incident","what","where"')
    assert [line.split(",")[1] for line in lines[1:]] == ['"W1"', '"E1"', '"T1"']

    page.click("#incident-table tbody tr[data-run='T1'] button")
    page.wait_for_function("document.getElementById('run-title').textContent.startsWith('T1 ')")
    assert page.inner_text("#run-title") == "T1 (sweep, aborted)"
    assert page.errors == []


def _get_json(url: str) -> Any:
    import json

    with urllib.request.urlopen(url, timeout=30) as r:  # noqa: S310 (our loopback server)
        return json.loads(r.read())


@pytest.mark.paced
def test_an_e_stop_between_runs_is_in_the_history_across_a_restart(tmp_path, web_factory):
    """Issue 25: an emergency stop pressed and released while no run is going is in no run
    file; the daemon's incident log keeps it, and /api/trips (JSON and CSV) lists it with its
    time, after the daemon's restart too, beside a press in the restarted daemon."""
    from datetime import UTC, datetime

    from control.wire.client import Subscriber
    from tests.e2e.test_board_safety_e2e import _wait_for_event, estop_rig
    from web.trips import IDLE_WHERE

    server, d = estop_rig(tmp_path)
    d2 = None
    try:
        url = web_factory(d, follow=True)

        def press_and_release(daemon: DaemonProcess) -> tuple[datetime, datetime]:
            with Subscriber(daemon.data, rcvhwm=0) as sub:
                sub.wait_connected()
                before = datetime.now(UTC)
                server.proc.send_signal(signal.SIGUSR1)
                server.next_line("emergency stop pressed", timeout_s=10)
                _wait_for_event(sub, "emergency stop pressed while idle")
                server.proc.send_signal(signal.SIGUSR2)
                server.next_line("emergency stop released", timeout_s=10)
                _wait_for_event(sub, "emergency stop released")  # logged before it is said
                return before, datetime.now(UTC)

        def idle_rows() -> list[dict[str, Any]]:
            out = _get_json(url + "api/trips?incident=e-stop")
            assert out["ok"] and out["log_lines_skipped"] == 0, out
            return [r for r in out["incidents"] if r["where"] == IDLE_WHERE]

        first = press_and_release(d)
        rows = idle_rows()
        assert [r["what"].split(" (")[0] for r in rows] == [  # newest first
            "emergency stop released", "emergency stop pressed while idle"]
        for r in rows:
            when = datetime.fromisoformat(r["time_utc"])
            assert first[0] <= when <= first[1], (r, first)
            assert r["run_id"] == "" and r["incident"] == "e-stop"
            assert r["peak_orbit_um"] is None and r["file"] == "incidents.jsonl"
        assert rows[1]["time_utc"] < rows[0]["time_utc"]

        # the daemon stopped and started again (new ports, found by the page through
        # daemon.json): the log survives, and the new daemon's press is added to it
        assert d.terminate() == 0
        d.proc.communicate(timeout=10)
        d2 = start_daemon(d.runs_dir, "--backend", "nidaqmx", "--grpc-target", server.address,
                          "--channels", str(tmp_path / "channels.toml"), fast=False)
        second = press_and_release(d2)
        rows = idle_rows()
        assert len(rows) == 4
        assert [datetime.fromisoformat(r["time_utc"]) >= second[0] for r in rows] == [
            True, True, False, False]
        with urllib.request.urlopen(url + "api/trips?format=csv",  # noqa: S310
                                    timeout=30) as r:
            lines = r.read().decode().splitlines()
        idle = [line for line in lines[1:] if IDLE_WHERE in line]
        assert len(idle) == 4 and all(',"","e-stop","emergency stop ' in line for line in idle)
    finally:
        for daemon in (d, d2):
            if daemon is not None and daemon.proc.poll() is None:
                daemon.terminate()
                daemon.proc.communicate(timeout=10)
        server.stop()


def test_the_history_pages_and_filters_in_the_browser(tmp_path, browser, daemon_factory,
                                                      web_factory):
    """101 runs: the page shows the newest 100, Older the oldest one, Newer back; the status
    filter asks the run index for the aborted runs only."""
    import h5py

    from storage.layout import LIBVER
    from tests.web.test_history import _write

    runs = tmp_path / "runs0"  # the runs directory of daemon_factory's first daemon
    runs.mkdir()
    _write(runs / "R000.h5", "R000", "2026-03-01T00:00:00.000+00:00", "completed", [20.0], 1)
    for i in range(1, 101):
        p = runs / f"R{i:03d}.h5"
        p.write_bytes((runs / "R000.h5").read_bytes())
        with h5py.File(p, "r+", libver=LIBVER) as f:
            f.attrs["run_id"] = f"R{i:03d}"
            f.attrs["start_time"] = f"2026-03-01T{i // 60:02d}:{i % 60:02d}:00.000+00:00"
            f.attrs["status"] = "aborted" if i % 25 == 0 else "completed"
    url = web_factory(daemon_factory(), follow=True)  # a daemon on that runs directory
    page = _open(browser, url)
    rows = "#runs tbody tr"
    page.wait_for_function(f"document.querySelectorAll('{rows}').length === 100")
    first = page.eval_on_selector(rows, "r => r.dataset.run")
    assert first == "R100"
    assert "101 in" in page.inner_text("#runs-info") and "1-100 shown" in page.inner_text(
        "#runs-info")
    assert page.is_disabled("#runs-newer") and not page.is_disabled("#runs-older")
    page.click("#runs-older")
    page.wait_for_function(f"document.querySelectorAll('{rows}').length === 1")
    assert page.eval_on_selector(rows, "r => r.dataset.run") == "R000"
    assert "101-101 shown" in page.inner_text("#runs-info") and page.is_disabled("#runs-older")
    page.click("#runs-newer")
    page.wait_for_function(f"document.querySelectorAll('{rows}').length === 100")
    page.select_option("#runs-status", "aborted,failed,interrupted")
    page.wait_for_function(f"document.querySelectorAll('{rows}').length === 4")
    got = page.eval_on_selector_all(rows, "rs => rs.map(r => r.dataset.run)")
    assert got == ["R100", "R075", "R050", "R025"]
    assert page.errors == []
