"""`sfdrig daemon`: the composition root of the acquisition daemon.

Chooses the backend from the command line (the simulated rig, paced to the wall clock or as fast
as possible, or NI-DAQmx through the local driver or a gRPC device server), loads the channel map
and rig configuration, and serves `control.daemon.daemon.Daemon` until SIGTERM or Ctrl-C, which shut
down the safe way (drives ramped to zero, run file closed valid, marked aborted with the reason).

The first line on stdout is ``command=<endpoint> data=<endpoint> board='<the board>'``
(shell-quoted: `shlex.split` reads it; the board as `daq.board.Board.describe` says it); the same
endpoints and the board go to ``RUNS_DIR/daemon.json`` for the client commands.

One daemon per runs directory (`control.daemon.instance`) and one tool per board
(`daq.board.board_lock`): a second one is refused with the first one's pid, command line and
endpoints, before it touches the runs directory or the board.
"""

from __future__ import annotations

import argparse
import logging
import math
import shlex
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from threadpoolctl import threadpool_limits

from control.daemon.daemon import Daemon, DaemonConfig
from control.daemon.instance import runs_lock
from control.daemon.lease import LEASE_RANGE_S
from control.wire.security import KeyFileError, load_server_keys
from daq.board import NIDAQMX, Board
from daq.channels import ChannelMap, default_channel_map, load_channel_map
from daq.errors import ChannelConfigError, DaqConnectionError, DaqError
from daq.locks import AlreadyRunning, InstanceLock
from sfdrig.commands._board import grpc_target_error, hold_board
from sfdrig.commands._client_args import DEFAULT_RUNS_DIR, STATE_FILE_NAME
from sfdrig.commands._native_memory import pin_mmap_threshold

if TYPE_CHECKING:  # imported where the backend is chosen
    from daq.backend import DaqBackend
    from rig_model.params import RigParams
from sfdrig.commands._priority import LEVELS, PriorityError, apply_priority

NAME = "daemon"
#: the regenerating AO ring by default [s] (integer and half-integer Hz are whole cycles)
DEFAULT_RING_S = 2.0
#: how much longer than the board's watchdog the ring must be [s]: a hung host's watchdog
#: expiry (drives 0 V) comes before an abort's fade (margin + fade <= 0.1 s) could replay
RING_OVER_WATCHDOG_S = 0.2
HELP = "run the acquisition daemon (state machine, sweeps, live data, run files)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--backend", choices=["sim", "nidaqmx"], default="sim",
                        help="sim: the simulated rig; nidaqmx: NI-DAQmx (default: %(default)s)")
    parser.add_argument("--grpc-target", metavar="HOST:PORT",
                        help="with --backend nidaqmx: an NI gRPC device server instead of the "
                             "local driver")
    parser.add_argument("--fast", action="store_true",
                        help="simulated rig as fast as possible, not paced to the wall clock "
                             "(tests, demo)")
    parser.add_argument("--command-endpoint", default="tcp://127.0.0.1:0",
                        help="ROUTER bind address; port 0 picks a free port (default: "
                             "%(default)s)")
    parser.add_argument("--data-endpoint", default="tcp://127.0.0.1:0",
                        help="PUB bind address; port 0 picks a free port (default: %(default)s)")
    parser.add_argument("--runs-dir", type=Path, default=DEFAULT_RUNS_DIR,
                        help="where run files go (default: %(default)s)")
    parser.add_argument("--rig", metavar="NAME|RIG.toml",
                        help="simulated rig: 'nominal' (the report's stated values, the "
                             "default), 'report' (calibrated to its measured tables) or a TOML")
    parser.add_argument("--channels", type=Path, metavar="CHANNELS.toml",
                        help="channel map (default: the report's 14 AI channels)")
    parser.add_argument("--seed", type=int, default=0, help="simulated rig noise seed")
    parser.add_argument("--keys", type=Path,
                        help="CURVE key directory (required to bind beyond loopback)")
    parser.add_argument("--sndhwm", type=int, default=1000,
                        help="PUB high-water mark per subscriber [messages]; 0 = unlimited "
                             "(default: %(default)s)")
    parser.add_argument("--watchdog-s", type=float, default=1.0, metavar="S",
                        help="with --backend nidaqmx: the board's watchdog timer [s]; if the "
                             "daemon stops feeding it this long (hung, killed, PC down) the "
                             "board turns the pump relay off and the drives to 0 V by itself; "
                             "0 = none (default: %(default)s)")
    parser.add_argument("--ao-ring-s", type=float, default=None, metavar="S",
                        help="the regenerating AO ring [s]: a late host makes the board repeat "
                             "what it holds instead of underflowing; 0: non-regenerating "
                             "(-200290 when the host is late). Default: 2 s, or with "
                             "--backend nidaqmx whole seconds >= the watchdog + 0.2 s (a hung "
                             "host is stopped by the watchdog before an abort's fade could "
                             "come round again), and none without a watchdog")
    parser.add_argument("--film-drain-s", type=float, default=30.0, metavar="S",
                        help="after the pump goes off, dry sweeps are refused this long while "
                             "the film drains (its dwells are recorded as dry); the simulated "
                             "film drains with a 5 s time constant; measure the real rig's "
                             "(default: %(default)s)")
    parser.add_argument("--operator-lease-s", type=float, default=10.0, metavar="S",
                        help="a structure test whose client (the terminal of `sfdrig "
                             "structure`, the page that started it) has not said it is alive "
                             "for this long is aborted, drives ramped to zero: its operator is "
                             "lost (1..60 s; sweeps have no lease; default: %(default)s)")
    parser.add_argument("--priority", choices=LEVELS, default="normal",
                        help="scheduling: high = nice -10, realtime = SCHED_FIFO; refused "
                             "with a reason where the OS does not allow it (default: "
                             "%(default)s)")
    parser.add_argument("--log-level", default="WARNING", help="(default: %(default)s)")


def ao_ring_s(args: argparse.Namespace) -> float | None:
    """The AO ring the arguments ask for (None: non-regenerating); see ``--ao-ring-s``."""
    if args.ao_ring_s is not None:
        return args.ao_ring_s if args.ao_ring_s > 0 else None
    if args.backend != "nidaqmx":
        return DEFAULT_RING_S
    if args.watchdog_s <= 0:
        return None  # a ring nothing stops if the host hangs: the non-regenerating stream
    return float(max(DEFAULT_RING_S, math.ceil(args.watchdog_s + RING_OVER_WATCHDOG_S)))


def build_backend(args: argparse.Namespace, channel_map: ChannelMap
                  ) -> tuple[DaqBackend, ChannelMap, RigParams | None]:
    """(backend, channel map, rig config or None), chosen from the arguments."""
    ring = ao_ring_s(args)
    if args.backend == "nidaqmx":
        from daq.nidaqmx_backend import NidaqmxBackend

        watchdog = args.watchdog_s if args.watchdog_s > 0 else None
        return (NidaqmxBackend(grpc_target=args.grpc_target, watchdog_timeout_s=watchdog,
                               ao_ring_s=ring), channel_map, None)
    from rig_model.params import RigParams, rig_params_named_or_file
    from simulated_hw.backend import SimulatedBackend

    params = rig_params_named_or_file(args.rig) if args.rig else RigParams()
    backend = SimulatedBackend(params, seed=args.seed, realtime=not args.fast, ao_ring_s=ring)
    return backend, channel_map, params


def argument_error(args: argparse.Namespace) -> str | None:
    """The first argument out of its range or at odds with another, as the line to print."""
    if args.grpc_target is not None and args.backend != "nidaqmx":
        return "daemon: --grpc-target needs --backend nidaqmx"
    if line := grpc_target_error("daemon", args.grpc_target):
        return line
    if not (args.watchdog_s == 0 or 0.05 <= args.watchdog_s <= 60):
        return f"daemon: --watchdog-s {args.watchdog_s:g} must be 0 (none) or 0.05..60 s"
    if not 0 <= args.film_drain_s <= 3600:
        return f"daemon: --film-drain-s {args.film_drain_s:g} must be 0..3600 s"
    low, high = LEASE_RANGE_S
    if not low <= args.operator_lease_s <= high:
        return (f"daemon: --operator-lease-s {args.operator_lease_s:g} must be "
                f"{low:g}..{high:g} s")
    ring = ao_ring_s(args)
    if ring is not None and not 0.5 <= ring <= 60:
        return f"daemon: --ao-ring-s {ring:g} must be 0 (non-regenerating) or 0.5..60 s"
    if ring is not None and args.backend == "nidaqmx" and \
            (args.watchdog_s <= 0 or args.watchdog_s + RING_OVER_WATCHDOG_S > ring):
        return (f"daemon: --ao-ring-s {ring:g} needs the board's watchdog, at most "
                f"{ring - RING_OVER_WATCHDOG_S:g} s (--watchdog-s {args.watchdog_s:g}): a ring "
                "repeats its drive for as long as a hung host leaves it")
    return None


def _settle_the_process(priority: str) -> None:
    """One BLAS thread, sample arrays freed to the kernel, and the scheduling asked for
    (`PriorityError` when it cannot be had)."""
    # One BLAS thread: OpenBLAS started its worker when numpy was imported, before the priority
    # below, so the worker stays at normal priority; a SCHED_FIFO acquisition thread whose
    # lock-in product waited on it was delayed by every other process (underflows at load 2-4)
    threadpool_limits(limits=1, user_api="blas")
    # Freed sample arrays go back to the kernel, not scattered over the malloc arenas: RSS flat
    # over days of sweeps (sfdrig.commands._native_memory)
    log = logging.getLogger("sfdrig.daemon")
    log.info("%s", pin_mmap_threshold())
    log.info("scheduling: %s", apply_priority(priority))


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=args.log_level.upper(), stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if line := argument_error(args):
        print(line, file=sys.stderr)
        return 2
    try:
        _settle_the_process(args.priority)
    except PriorityError as err:
        print(f"daemon: {err}", file=sys.stderr)
        return 2
    try:
        channel_map = load_channel_map(args.channels) if args.channels else default_channel_map()
        keys = load_server_keys(args.keys) if args.keys else None
    except ChannelConfigError as err:
        for line in err.lines():
            print(f"daemon: {line}", file=sys.stderr)
        return 2
    except (KeyFileError, ValueError, OSError) as err:
        print(f"daemon: {err}", file=sys.stderr)
        return 2
    try:
        locks = take_locks(args, channel_map)
    except AlreadyRunning as err:
        print(f"daemon: {err}: stop it first"
              + (", or give another --runs-dir" if "runs directory" in str(err) else ""),
              file=sys.stderr)
        return 1
    except OSError as err:
        where = err.filename or args.runs_dir  # the runs directory, or the device locks' dir
        print(f"daemon: cannot use {where} (for its lock file): {err.strerror or err}",
              file=sys.stderr)
        return 2
    try:
        backend, channel_map, rig = build_backend(args, channel_map)
    except (ChannelConfigError, KeyFileError, DaqError, ValueError, OSError) as err:
        print(f"daemon: {err}", file=sys.stderr)
        return 2
    config = DaemonConfig(
        runs_dir=args.runs_dir, command_endpoint=args.command_endpoint,
        data_endpoint=args.data_endpoint, keys=keys, rig_config=rig, sndhwm=args.sndhwm,
        lossless_publish=args.fast, state_file=args.runs_dir / STATE_FILE_NAME,
        film_drain_s=args.film_drain_s, operator_lease_s=args.operator_lease_s,
    )
    try:
        hands = None
        if args.backend == "sim":  # on the real rig a person's hands do these
            from sfdrig.simulated_operator import SimulatedHands
            from simulated_hw.backend import SimulatedBackend

            if isinstance(backend, SimulatedBackend):  # what build_backend made for "sim"
                hands = SimulatedHands(backend, seed=args.seed)
        daemon = Daemon(backend, channel_map, config, hands=hands)
    except (PermissionError, DaqError, ChannelConfigError) as err:
        # e.g. --backend nidaqmx without the NI-DAQmx driver: one line, no traceback
        local = args.backend == "nidaqmx" and (args.grpc_target or channel_map.grpc_target) is None
        hint = (" (install NI-DAQmx, give --grpc-target HOST:PORT of an NI gRPC device server, "
                "or use --backend sim)" if isinstance(err, DaqConnectionError) and local else "")
        print(f"daemon: {' '.join(str(err).split())}{hint}", file=sys.stderr)
        _close_quietly(backend)
        return 2
    for lock in locks:
        lock.update(command=daemon.endpoints["command"], data=daemon.endpoints["data"])
    # Hand the GIL over every millisecond (default 5 ms): the acquisition thread's AO lead is
    # tens of milliseconds, and the writer, publisher and command threads must not eat it.
    sys.setswitchinterval(0.001)
    signal.signal(signal.SIGTERM, lambda s, f: daemon.stop("SIGTERM received"))
    signal.signal(signal.SIGINT, lambda s, f: daemon.stop("SIGINT (Ctrl-C) received"))
    print(f"command={daemon.endpoints['command']} data={daemon.endpoints['data']} "
          f"board={shlex.quote(daemon.board.describe())}", flush=True)
    daemon.serve()  # removes daemon.json on the way out, while the locks are still held
    for lock in locks:
        lock.release()
    return 0


def take_locks(args: argparse.Namespace, channel_map: ChannelMap) -> list[InstanceLock]:
    """The runs directory's lock (`control.daemon.instance`) and, on a board, the board's
    (`daq.board.board_lock`); held for the life of the process (the kernel drops them when it
    ends, however it ends)."""
    runs_dir = Path(args.runs_dir)
    locks = [runs_lock(runs_dir).acquire(daemon=True)]
    if args.backend == "nidaqmx":
        target = args.grpc_target if args.grpc_target is not None else channel_map.grpc_target
        try:
            lock = hold_board(Board(NIDAQMX, channel_map.device.name, target), daemon=True,
                              runs_dir=str(runs_dir.resolve()))
        except BaseException:
            locks[0].release()
            raise
        if lock is not None:
            locks.append(lock)
    return locks


def _close_quietly(backend: DaqBackend) -> None:
    try:
        backend.close()
    except Exception:  # noqa: BLE001 - already failing; the first error is the one shown
        logging.getLogger("sfdrig.daemon").debug("closing the backend failed", exc_info=True)
