"""Run one of NI's nidaqmx examples unchanged against a gRPC device server (``sfdrig sim-server``).

Usage: ``python nidaqmx_example_runner.py HOST:PORT EXAMPLE.py [--loops N] [--patience S]
[--enter-after S]``

Only what a lab engineer changes to move a program onto the server is supplied: the session
(every ``nidaqmx.Task``, ``System.local()`` and ``nidaqmx.system.Device`` get the server's
``grpc_options``) and the device names (requests naming another board's device are renamed to
the server's ``Dev1`` on the wire, by a client interceptor; ``Dev2`` stays: there is one board).
The user's hand is simulated too: ``input()`` ("press Enter to stop") returns once the example's
events have been called ``N`` times (or after ``S`` seconds, 30 by default: a task waiting on a
trigger that never comes; if it registered none, at once or after ``--enter-after`` seconds:
a program whose threads read until Enter), and the
``N + 1``-th read or write of a ``while True`` loop raises ``KeyboardInterrupt`` (Ctrl+C), which
the examples catch. Plots are drawn off screen.

Prints the example's output, then one line ``RESULT {json}``: ``status`` ``ok``, ``daqerror``
(with ``code`` and ``message``) or ``error`` (any other exception: ``type``, ``message``), the
reads/writes made, the event callbacks invoked and the wall time.
"""

from __future__ import annotations

import builtins
import json
import os
import re
import runpy
import sys
import threading
import time
import traceback
from typing import Any

os.environ.setdefault("MPLBACKEND", "Agg")

import grpc  # noqa: E402
import nidaqmx  # noqa: E402
import nidaqmx.system  # noqa: E402
from nidaqmx.errors import DaqError, DaqWarning  # noqa: E402

#: other boards' device names in NI's examples -> the simulated board
DEVICE_NAMES = {"cDAQ1Mod1": "Dev1", "cdaqTesterMod4": "Dev1", "PXI1Slot2": "Dev1",
                "PXI1Slot3": "Dev1", "PXI1Slot7": "Dev1", "TS1Mod1": "Dev1"}
_NAMES = re.compile(r"\b(" + "|".join(DEVICE_NAMES) + r")\b")


def _rename(request: Any) -> Any:
    fields = [f for f in request.DESCRIPTOR.fields
              if f.type == f.TYPE_STRING and not f.is_repeated]
    changed = {f.name: _NAMES.sub(lambda m: DEVICE_NAMES[m[1]], getattr(request, f.name))
               for f in fields}
    changed = {k: v for k, v in changed.items() if v != getattr(request, k)}
    if not changed:
        return request
    out = type(request)()
    out.CopyFrom(request)
    for k, v in changed.items():
        setattr(out, k, v)
    return out


class _Renamer(grpc.UnaryUnaryClientInterceptor, grpc.UnaryStreamClientInterceptor):
    def intercept_unary_unary(self, continuation, details, request):  # type: ignore[no-untyped-def]
        return continuation(details, _rename(request))

    def intercept_unary_stream(self, continuation, details, request):  # type: ignore[no-untyped-def]
        return continuation(details, _rename(request))


class _Hand:
    """The user: Ctrl+C after ``loops`` reads/writes, Enter after ``loops`` events."""

    def __init__(self, loops: int, patience_s: float, enter_after_s: float = 0.0) -> None:
        self.loops = loops
        self.patience_s = patience_s  # how long the user waits for events before Enter
        self.enter_after_s = enter_after_s  # ... and with no events: watching it run
        self.calls = 0
        self.events = 0
        self.enough = threading.Event()
        self.ctrl_c = True
        self.registered = 0  # event callbacks registered

    def call(self) -> None:
        self.calls += 1
        if self.calls >= self.loops and self.events == 0:
            self.enough.set()
        if self.ctrl_c and self.calls > self.loops and self.events == 0 \
                and threading.current_thread() is threading.main_thread():
            raise KeyboardInterrupt

    def event(self) -> None:
        self.events += 1
        if self.events >= self.loops:
            self.enough.set()

    def input(self, prompt: object = "") -> str:
        """Enter: after ``loops`` events (or ``patience_s``), at once when nothing will call
        back."""
        print(prompt, end="")
        if self.registered:
            self.enough.wait(self.patience_s)
        elif self.enter_after_s:
            time.sleep(self.enter_after_s)  # the user, not a synchronisation
        return ""


def main(argv: list[str]) -> int:
    address, path = argv[0], argv[1]
    loops = int(argv[argv.index("--loops") + 1]) if "--loops" in argv else 3
    patience_s = float(argv[argv.index("--patience") + 1]) if "--patience" in argv else 30.0
    enter_after_s = (float(argv[argv.index("--enter-after") + 1]) if "--enter-after" in argv
                     else 0.0)
    channel = grpc.intercept_channel(grpc.insecure_channel(address), _Renamer())
    options = nidaqmx.GrpcSessionOptions(channel, "")
    hand = _Hand(loops, patience_s, enter_after_s)
    with open(path) as source:  # only a program that waits for Ctrl+C gets one
        hand.ctrl_c = "KeyboardInterrupt" in source.read()

    task_init = nidaqmx.Task.__init__

    def task_with_session(self, new_task_name="", *, grpc_options=None):  # type: ignore[no-untyped-def]
        task_init(self, new_task_name, grpc_options=grpc_options or options)

    nidaqmx.Task.__init__ = task_with_session  # type: ignore[method-assign]
    device_init = nidaqmx.system.Device.__init__

    def device_with_session(self, name, *, grpc_options=None):  # type: ignore[no-untyped-def]
        device_init(self, name, grpc_options=grpc_options or options)

    nidaqmx.system.Device.__init__ = device_with_session  # type: ignore[method-assign]
    nidaqmx.system.System.local = staticmethod(  # type: ignore[method-assign]
        lambda: nidaqmx.system.System.remote(options))

    for name in ("read", "write", "read_waveform", "write_waveform"):
        original = getattr(nidaqmx.Task, name, None)
        if original is None:
            continue

        def counted(self, *a, _original=original, **k):  # type: ignore[no-untyped-def]
            hand.call()
            return _original(self, *a, **k)

        setattr(nidaqmx.Task, name, counted)
    for name in [n for n in dir(nidaqmx.Task) if n.startswith("register_")]:
        original = getattr(nidaqmx.Task, name)

        def register(self, *a, _original=original, **k):  # type: ignore[no-untyped-def]
            args = list(a)
            fn_index = next((i for i, v in enumerate(args) if callable(v)), None)
            if fn_index is not None:
                hand.registered += 1
                user = args[fn_index]

                def callback(*c):  # type: ignore[no-untyped-def]
                    hand.event()
                    return user(*c)

                args[fn_index] = callback
            return _original(self, *args, **k)

        setattr(nidaqmx.Task, name, register)
    builtins.input = hand.input

    try:
        import matplotlib.pyplot as plt
        plt.show = lambda *a, **k: None
    except ImportError:
        pass

    result: dict[str, Any]
    t0 = time.monotonic()
    sys.argv = [path]
    try:
        runpy.run_path(path, run_name="__main__")
        result = {"status": "ok"}
    except DaqError as err:
        result = {"status": "daqerror", "code": err.error_code, "message": str(err)[:400]}
    except DaqWarning as warn:
        result = {"status": "daqerror", "code": warn.error_code, "message": str(warn)[:400]}
    except SystemExit as ex:
        result = {"status": "ok" if not ex.code else "error", "type": "SystemExit",
                  "message": str(ex.code)}
    except BaseException as err:  # noqa: BLE001 - reported, not handled
        result = {"status": "error", "type": type(err).__name__, "message": str(err)[:400],
                  "traceback": traceback.format_exc()[-1500:]}
    result.update(calls=hand.calls, events=hand.events,
                  wall_s=round(time.monotonic() - t0, 3))
    sys.stdout.flush()
    print("\nRESULT " + json.dumps(result), flush=True)
    channel.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
