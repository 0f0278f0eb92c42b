"""The terminal front end of the operator protocol (`control.run.programs.operator`): shows the
question the
daemon's running test asks, reads what the person types, sends it as an answer and shows the
daemon's refusal (wrong unit, out of range) until an answer is accepted. The browser view is the
other front end of the same protocol; neither decides anything the daemon does not check.

While it is the operator, the terminal renews the test's operator lease (`control.daemon.lease`):
if this process is killed, the daemon aborts the test once the lease lapses. An abort typed at
any moment is sent: as the answer to the question asked, or as an abort when none is (between
two questions, or at a question that does not offer it). End of input sends an abort too."""

from __future__ import annotations

import select
import time
from typing import Any, NamedTuple, TextIO

from control.wire.client import CommandClient
from control.wire.heartbeat import AskedQuestion, LastRun
from control.wire.protocol import renew_every_s

POLL_S = 0.2  # how often the daemon's status is read while waiting [s]
KEYS = {"": "ok", "y": "ok", "ok": "ok", "accept": "ok", "r": "repeat", "repeat": "repeat",
        "s": "skip", "skip": "skip", "a": "abort", "abort": "abort", "n": "reject",
        "reject": "reject", "d": "double", "double": "double", "o": "overload",
        "overload": "overload"}
SHOWN = {"ok": "Enter accept", "repeat": "r repeat", "skip": "s skip", "abort": "a abort",
         "reject": "n reject", "double": "d double hit", "overload": "o overload"}


def describe(q: AskedQuestion) -> str:
    """The question as the terminal shows it."""
    lines = [f"[{q['where']}] #{q['id']}", f"  {q['prompt']}"]
    lines += [f"  {line}" for line in q.get("info", [])]
    if q.get("shows"):
        lines.append(f"  the simulated instrument shows: {q['shows']}")
    keys = [SHOWN[c] for c in q["choices"] if c in SHOWN]
    entry = q.get("entry")
    if entry is not None:
        keys[0:1] = [f"type the {entry['label']} [{entry['unit']}]"] if "ok" in q["choices"] \
            else keys[0:1]
    elif q.get("trigger") and "ok" in q["choices"]:
        keys[0:1] = ["Enter strike"]
    if q.get("trigger"):
        lines.append("  (waiting for the hammer on the armed channel)")
    lines.append("  " + ", ".join(keys))
    return "\n".join(lines)


def interpret(line: str, q: AskedQuestion) -> tuple[str, str]:
    """(choice, text) for a typed line: a choice key or word, else the entry's text. The daemon
    checks and logs it (an unknown word is sent as it is, so its refusal is in the run)."""
    word = line.strip().lower()
    choice = KEYS.get(word)
    if q.get("entry") is not None and "ok" in q["choices"] and (choice is None or
                                                                 choice == "ok"):
        return "ok", line.strip()
    return (choice or line.strip()[:32] or "?"), ""


def _read_line(inp: TextIO, timeout_s: float) -> str | None:
    """A line typed within ``timeout_s``; "" at end of input is returned as None with EOF."""
    ready, _, _ = select.select([inp], [], [], timeout_s)
    if not ready:
        return None
    return inp.readline()


class EndOfTest(NamedTuple):
    """How a structure test ended: the daemon's record of it, and the steps it recorded."""

    run: LastRun
    steps: int


def run_test(client: CommandClient, test: str, spec: dict[str, Any], operator: str,
             notes: str, inp: TextIO, out: TextIO) -> EndOfTest:
    """Start ``test`` on the daemon, be its operator until it ends: the daemon's record of how
    it ended (run_id, path, status, reason) and the steps it recorded."""
    reply = client.request("start_test", test=test, spec=spec, operator=operator, notes=notes)
    run_id = reply.data["run_id"]
    print(f"{test}: run {run_id} started: {reply.data['path']}", file=out, flush=True)
    lease = reply.data.get("lease", "")
    every_s = renew_every_s(float(reply.data.get("lease_s", 0.0)))
    renew_at = time.monotonic() + every_s
    shown: AskedQuestion | None = None
    steps = 0
    closed = False  # the abort is sent (or input ended): nothing more is read
    answered = 0  # the last question this terminal answered
    while True:
        if lease and time.monotonic() >= renew_at:
            # refused once the test has ended: the status below then says how it ended
            client.request("alive", check=False, lease=lease)
            renew_at = time.monotonic() + every_s
        st = client.status()
        if st["run_id"] != run_id:
            if st["last_run"].get("run_id") == run_id:
                return EndOfTest(st["last_run"], steps)
            time.sleep(POLL_S)  # between the run's end and the daemon's record of it
            continue
        done = st["progress"].get("steps_done", steps)
        steps = done if isinstance(done, int) else steps
        q = st["question"]
        if q is not None and (shown is None or q["id"] != shown["id"]):
            print(describe(q), file=out)
            print("> ", end="", file=out, flush=True)
        elif q is None and shown is not None and shown.get("trigger") \
                and shown["id"] != answered:
            print("\n  (strike seen on the armed channel)", file=out, flush=True)
        shown = q
        if closed:
            time.sleep(POLL_S)
            continue
        line = _read_line(inp, POLL_S)
        if line is None:
            continue
        if line == "":  # end of input: nobody is left to answer
            closed = True
            client.abort("the operator's input closed")
            print("\ninput closed: abort sent (drives ramp to zero)", file=out, flush=True)
            continue
        typed_abort = KEYS.get(line.strip().lower()) == "abort"
        if typed_abort and (q is None or "abort" not in q["choices"]):
            closed = True
            client.abort("the operator typed abort at the terminal"
                         + ("" if q is None else f" ({q['where']})"))
            print("  = abort sent (drives ramp to zero)", file=out, flush=True)
            continue
        if q is None:
            print("  (nothing is asked now)", file=out, flush=True)
            continue
        choice, text = interpret(line, q)
        answer = client.request("answer", check=False, question_id=q["id"], choice=choice,
                                text=text)
        if not answer.ok and typed_abort:  # the question went meanwhile: abort all the same
            closed = True
            client.abort(f"the operator typed abort at the terminal ({q['where']})")
            print("  = abort sent (drives ramp to zero)", file=out, flush=True)
        elif not answer.ok:
            print(f"  ! {answer.error}\n> ", end="", file=out, flush=True)
        else:
            answered = q["id"]
            print(f"  = {choice}" + (f" {text}" if text else ""), file=out, flush=True)


__all__ = ["EndOfTest", "describe", "interpret", "run_test"]
