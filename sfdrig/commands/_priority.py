"""`--priority` for the daemon: ask the OS to schedule the acquisition ahead of other work.

- ``normal``: leave the scheduling alone;
- ``high``: nice -10 (``setpriority``);
- ``realtime``: SCHED_FIFO at priority 10 (Linux; threads created afterwards inherit it, so call
  this before the daemon starts its threads). Python keeps its GIL: the point is that other
  processes on the machine no longer delay the AO writes.

Where the OS refuses (no permission, no such policy) `PriorityError` says why and what to do;
the daemon then does not start, rather than run at a priority it was not asked for.
"""

from __future__ import annotations

import os

LEVELS = ("normal", "high", "realtime")
NICE_HIGH = -10
FIFO_PRIORITY = 10


class PriorityError(OSError):
    """The OS did not grant the scheduling asked for; the message says why and what to do."""


def apply_priority(level: str) -> str:
    """Apply ``level`` to this process; return what was applied, in words."""
    if level == "normal":
        return "normal scheduling"
    if level == "high":
        try:
            os.setpriority(os.PRIO_PROCESS, 0, NICE_HIGH)
        except (PermissionError, AttributeError) as err:
            raise PriorityError(
                f"--priority high: the OS refused nice {NICE_HIGH} ({err}); run as root, or "
                "raise the user's 'nice' limit in /etc/security/limits.conf") from None
        return f"nice {os.getpriority(os.PRIO_PROCESS, 0)}"
    if level == "realtime":
        if not hasattr(os, "sched_setscheduler"):
            raise PriorityError("--priority realtime: this OS has no SCHED_FIFO "
                                "(os.sched_setscheduler); use --priority high or normal")
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
        except PermissionError as err:
            raise PriorityError(
                f"--priority realtime: the OS refused SCHED_FIFO ({err}); run as root, give "
                "the user an 'rtprio' limit in /etc/security/limits.conf, or grant "
                "CAP_SYS_NICE (in a container: --cap-add SYS_NICE)") from None
        return f"SCHED_FIFO priority {os.sched_getparam(0).sched_priority}"
    raise ValueError(f"priority {level!r} is not one of {', '.join(LEVELS)}")
