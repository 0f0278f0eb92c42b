"""A simulated NI-DAQmx gRPC Device Server: the rig behind the official ``nidaqmx`` client.

The servicer subclasses the one shipped in the pinned ``nidaqmx`` package, so the official
client (``nidaqmx.Task(grpc_options=...)``) drives it exactly as it would drive NI's own server.
It serves one device (``Dev1`` by default: ai0..ai15, ao0..ao1, port0/line0..7) wired to one
`rig_model.rig.RigModel`: each AI terminal carries the sensor the wiring map puts there, each
AO terminal drives the shaker of its axis, and the relay line switches the oil pump.

Supported, as a multifunction board accepts them: AI hardware-timed (continuous or finite, on
the onboard clock; a read starts a task not started, and stops a finite one at its end) or on
demand; AO on ``/Dev1/ai/SampleClock`` armed on ``/Dev1/ai/StartTrigger`` (AI sample ``k`` is
taken while AO sample ``k`` is generated, as sfdrig uses it) or on its own clock, regenerating
(nidaqmx's default) or not, continuous or finite, or on demand; the AO idle output behaviour
(0 V or hold); DO lines, and DI lines (the emergency stop of the wiring map, if any); the
internal channels ``Dev1/_aoN_vs_aognd``; IsTaskDone / WaitUntilTaskDone; the watchdog timer
task with DO and AO expiration states, expired by the board's own timer thread. What a board
refuses gets its DAQmx code (-200462 empty output buffer, -50103 a second AI task, -200560 a
continuous task never done, -200278 past the end of a finite acquisition, -200644 / -200678
after a watchdog expiry, ...); an RPC it does not serve answers the DAQmx error the board or
the driver gives for it (`simulated_hw.board.refusals`: -201380 counters and waveforms, -200431 a
measurement the inputs lack, -200197 an attribute, ...), never UNIMPLEMENTED. Also served: port
and line DIO (hardware-timed too), the every-N-samples and done events, thermocouple channels,
the attributes generic programs ask for (README, "Against the real rig"). The rig is never reset:
each acquisition continues it (`SimDevice.carried`).

Time: paced (default), samples become available as the wall clock advances (a read waits;
too long -> DAQmx -200284; a reader more than the input buffer behind -> -200279; an AO writer
behind the generation -> -200290, the output then goes to its idle state). ``fast=True``
generates samples the moment they are read (no timeouts, no overflow; AO still underflows when
a read needs samples that were never written); the device clock then moves only with AI reads,
waits and on-demand reads (1 ms each). The watchdog timer always runs on the wall clock.

Errors go back as NI's server sends them: gRPC status UNKNOWN with trailing metadata
``ni-error: <code>`` (plus ``ni-samps-per-chan-read`` on reads), so the client raises
``nidaqmx.errors.DaqError`` with the real DAQmx code. One decorator,
`simulated_hw.board.wire.reports_daq_errors`, does that for every RPC; handlers just raise
`daq.errors.DaqError`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent import futures

import grpc
from nidaqmx._stubs import nidaqmx_pb2 as pb
from nidaqmx._stubs import nidaqmx_pb2_grpc as pb_grpc

from daq.channels import ChannelMap, default_channel_map
from rig_model.params import RigParams
from simulated_hw.board.codes import SERVICE_NAME
from simulated_hw.board.device import SimDevice
from simulated_hw.board.servicer import SimulatedDaqmxServicer
from simulated_hw.board.wire import serialize_reply

_log = logging.getLogger(__name__)


# --- the server -----------------------------------------------------------------------------
class SimulatedDeviceServer:
    """A gRPC server on ``host:port`` (port 0: any free port) serving one `SimDevice`.

    Use as a context manager, or ``start()`` / ``stop()``. ``address`` is ``"host:port"``.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        params: RigParams | None = None,
        seed: int = 0,
        fast: bool = False,
        wiring: ChannelMap | None = None,
        max_message_bytes: int = 256 * 1024 * 1024,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] | None = None,
        max_workers: int = 8,
    ) -> None:
        self.device = SimDevice(wiring or default_channel_map(), params or RigParams(), seed,
                                fast, clock, sleep)
        self.servicer = SimulatedDaqmxServicer(self.device)
        options = [("grpc.max_send_message_length", max_message_bytes),
                   ("grpc.max_receive_message_length", max_message_bytes),
                   ("grpc.so_reuseport", 0)]
        self._executor = futures.ThreadPoolExecutor(max_workers=max_workers,
                                                    thread_name_prefix="sim-daqmx")
        self._server = grpc.server(self._executor, options=options)
        # ReadAnalogF64 answers with pre-encoded bytes (`_read_reply`); this handler, added
        # before the package's, passes them through. Every other RPC is the package's.
        raw_reads = grpc.method_handlers_generic_handler(SERVICE_NAME, {
            "ReadAnalogF64": grpc.unary_unary_rpc_method_handler(
                self.servicer.ReadAnalogF64,
                request_deserializer=pb.ReadAnalogF64Request.FromString,
                response_serializer=serialize_reply,
            ),
        })
        self._server.add_generic_rpc_handlers((raw_reads,))
        pb_grpc.add_NiDAQmxServicer_to_server(self.servicer, self._server)
        self.host = host
        self.port = self._server.add_insecure_port(f"{host}:{port}")
        if self.port == 0:
            raise OSError(f"cannot bind the simulated device server to {host}:{port}")

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    def start(self) -> SimulatedDeviceServer:
        self._server.start()
        _log.info("simulated NI-DAQmx device server on %s", self.address)
        return self

    def stop(self, grace_s: float | None = 1.0) -> None:
        self.device.shutdown()
        self._server.stop(grace_s).wait()
        self._executor.shutdown(wait=True)

    def wait(self) -> None:
        self._server.wait_for_termination()

    def reset(self) -> None:
        """Clear every task on the server (a fresh device, as after ResetDevice)."""
        self.servicer.reset()

    def __enter__(self) -> SimulatedDeviceServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
