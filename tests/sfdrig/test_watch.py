"""`sfdrig watch` against a stand-in daemon (`tests.fake_daemon`): a message it cannot use is
skipped and counted, never the end of the watch (issue 25: one 2-frame message killed the
page's feed; the command-line watch had the same weakness)."""

from __future__ import annotations

import subprocess
import sys
import threading

from control.wire.protocol import encode_header
from tests.fake_daemon import block_message


def test_watch_skips_malformed_messages_and_goes_on(fakes):
    daemon = fakes("A")
    header, payload = block_message(0)
    bad = [[b"block", encode_header({"seq": 0})],                     # 2 frames
           [b"status", b"{bad", b""], [b"status", b"null", b""],      # bad JSON; not an object
           [b"block", encode_header({**header, "seq": 0}), payload[:-8]],  # short payload
           [b"step", encode_header({"seq": 0}), b""],                 # no step inside
           [b"block", b"\xff\xfe", b""]]                              # not UTF-8
    stop = threading.Event()

    def publish() -> None:  # until the watch has ended: it connects whenever it connects
        first = 0
        while not stop.wait(0.05):
            for frames in bad:
                daemon.raw(frames)
            h, p = block_message(first)
            daemon.send("block", h, p)
            first += 100

    sender = threading.Thread(target=publish, daemon=True)
    sender.start()
    try:
        out = subprocess.run(
            [sys.executable, "-m", "sfdrig", "watch", "--data-endpoint", daemon.data,
             "--command-endpoint", daemon.command, "--count", "3", "--interval", "0.3"],
            capture_output=True, text=True, timeout=60)
    finally:
        stop.set()
        sender.join(5)
    assert out.returncode == 0, out.stderr
    assert "Traceback" not in out.stderr
    assert out.stderr.startswith("watch: skipped a malformed message (")
    tables = [t for t in out.stdout.split("state ") if t]
    assert len(tables) == 3
    # the last table still shows the blocks that came after the bad messages, and the count
    last = tables[-1]
    assert "skipped" in last.splitlines()[0] and "malformed" in last.splitlines()[0]
    skipped = int(last.splitlines()[0].split("skipped ")[1].split()[0])
    assert skipped >= len(bad)
    assert {"fx", "x1", "shaker_x"} <= {ln.split()[0] for ln in last.splitlines()[2:]}
