"""NI's wire format, as the NI gRPC Device Server speaks it: DAQmx errors as gRPC status UNKNOWN
with trailing metadata ``ni-error`` (and ``ni-samps-per-chan-read``), and AI reads encoded straight
from numpy."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import grpc
import numpy as np

from daq.errors import DaqError
from simulated_hw.board.codes import UNKNOWN_ERROR


def _bare_message(err: DaqError) -> str:
    return getattr(err, "bare_message", None) or str(err)


def reports_daq_errors(method: Callable[..., Any]) -> Callable[..., Any]:
    """The one place where our `DaqError` becomes NI's wire format: status UNKNOWN, trailing
    metadata ``ni-error`` (and ``ni-samps-per-chan-read`` for reads)."""

    @functools.wraps(method)
    def wrapper(self: Any, request: Any, context: grpc.ServicerContext) -> Any:
        try:
            return method(self, request, context)
        except DaqError as err:
            abort_with(context, err)

    return wrapper


def abort_with(context: grpc.ServicerContext, err: DaqError) -> None:
    """End the RPC with ``err`` in NI's wire format (raises, as ``context.abort`` does)."""
    metadata = [("ni-error", str(err.code or UNKNOWN_ERROR))]
    samps = getattr(err, "samps_per_chan_read", None)
    if samps is not None:
        metadata.append(("ni-samps-per-chan-read", str(samps)))
    context.set_trailing_metadata(metadata)
    context.abort(grpc.StatusCode.UNKNOWN, _bare_message(err))


_READ_ARRAY_TAG = b"\x12"  # field 2 (read_array), wire type 2 (packed)
_SAMPS_READ_TAG = b"\x18"  # field 3 (samps_per_chan_read), varint


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def read_reply(data: np.ndarray, samps_per_chan: int) -> bytes:
    """The serialized ``ReadAnalogF64Response``, encoded straight from numpy: status 0 (the
    default, omitted), packed ``read_array``, ``samps_per_chan_read``. Building the message
    field by field costs ~40-100 ns per sample, more than the rest of the read."""
    payload = np.ascontiguousarray(data, dtype="<f8").tobytes()
    return (_READ_ARRAY_TAG + _varint(len(payload)) + payload
            + _SAMPS_READ_TAG + _varint(samps_per_chan))


def serialize_reply(reply: bytes | Any) -> bytes:
    return reply if isinstance(reply, bytes) else reply.SerializeToString()
