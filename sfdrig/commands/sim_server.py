"""`sfdrig sim-server`: the simulated NI-DAQmx gRPC device server (the rig behind nidaqmx)."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

NAME = "sim-server"
HELP = ("serve a simulated NI-DAQmx device (Dev1 wired to the simulated rig) over gRPC, for "
        "the nidaqmx backend.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--port", type=int, required=True,
                        help="TCP port; 0 picks a free one (the first line of stdout says which)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to bind (default: %(default)s)")
    parser.add_argument("--rig", default="nominal", metavar="NAME|RIG.toml",
                        help="simulated rig: 'nominal' (the report's stated values, the default), "
                             "'report' (calibrated to its measured tables) or a TOML")
    parser.add_argument("--channels",
                        help="wiring: channel map TOML saying which sensor is on which terminal "
                             "(default: the report's channel map)")
    parser.add_argument("--journal", choices=["in", "out"], default="in",
                        help="in: the rig assembled (the seal's friction, about 26 N, holds the "
                             "housing under small forces); out: the structure alone, as `sfdrig "
                             "commission` drives it and the static tests load it (default: "
                             "%(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed (default: %(default)s)")
    parser.add_argument("--fast", action="store_true",
                        help="generate samples as fast as they are read instead of in real time")


def run(args: argparse.Namespace) -> int:
    import logging

    # the board's own events (a watchdog expiring) go to stderr, as a device's log would
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    from daq.channels import default_channel_map, load_channel_map
    from daq.errors import ChannelConfigError
    from rig_model.params import RigParamsError, rig_params_named_or_file
    from simulated_hw.grpc_server import SimulatedDeviceServer

    if not 0 <= args.port <= 65535:
        print(f"sim-server: --port {args.port} is not a TCP port (0..65535)", file=sys.stderr)
        return 2
    try:
        params = rig_params_named_or_file(args.rig)
        if args.journal == "out":
            params.journal_in = False
        wiring = load_channel_map(args.channels, wiring=True) if args.channels \
            else default_channel_map()
    except ChannelConfigError as err:
        for line in err.lines():
            print(f"sim-server: {line}", file=sys.stderr)
        return 2
    except RigParamsError as err:
        print(f"sim-server: {err}", file=sys.stderr)
        return 2
    try:
        server = SimulatedDeviceServer(args.host, args.port, params=params, seed=args.seed,
                                       fast=args.fast, wiring=wiring)
    except (OSError, RuntimeError) as err:
        print(f"sim-server: cannot listen on {args.host}:{args.port}: {err}", file=sys.stderr)
        return 1
    done = threading.Event()

    def _on_signal(signum: int, _frame: object) -> None:
        done.set()

    signal.signal(signal.SIGTERM, _on_signal)
    signal.signal(signal.SIGINT, _on_signal)
    # the emergency-stop button of the wiring map (if it has one): SIGUSR1 presses, SIGUSR2
    # releases it, as a hand on the rig would
    signal.signal(signal.SIGUSR1, lambda s, f: server.device.press_estop(True))
    signal.signal(signal.SIGUSR2, lambda s, f: server.device.press_estop(False))
    server.start()
    mode = "fast" if args.fast else "real time"
    print(f"listening on {server.address}", flush=True)
    print(f"device {wiring.device.name} ({wiring.device.product}), seed {args.seed}, {mode}, "
          f"journal {'in' if params.journal_in else 'out'}; "
          "stop with Ctrl-C or SIGTERM", flush=True)
    if wiring.estop is not None:
        print(f"emergency stop on {wiring.estop.physical_channel}: SIGUSR1 presses it, SIGUSR2 "
              "releases it", flush=True)
    while not done.wait(0.5):
        pass
    server.stop(grace_s=1.0)
    print("sim-server stopped", flush=True)
    return 0
