"""The AI read and the AO write through gRPC with their samples as one packed array.

nidaqmx's gRPC interpreter turns every sample into a Python float on the way: a read's reply is
copied out of the protobuf ``repeated double`` element by element, and a write's numpy array is
put into the request the same way (about 0.1 us a sample: a 14-channel 10 ms block cost a paced
daemon as much as the round trip itself, a 3,000-sample ring write 0.6 ms). Both are the same
bytes on the wire as a numpy array's little-endian float64 memory (proto3 packs a repeated
double: one length-delimited field of 8-byte values), so here

- `packed_reads` gives a task's stub a ``ReadAnalogF64`` whose reply keeps ``read_array`` as
  one numpy view of the reply's bytes (the interpreter then copies it into the caller's array
  in one piece; errors still come through the interpreter's own handling), and
- `PackedWriter` sends ``WriteAnalogF64`` with the array's bytes appended to the request's other
  fields (protobuf reads fields in any order), through the interpreter's error handling.

Nothing changes on the wire; the local driver (no gRPC) is left as it is. The message layouts
are nidaqmx 1.7.0's (pinned in pyproject.toml); `tests/daq/test_nidaqmx_packed.py` checks them
against the package's own protobuf classes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["PackedWriter", "packed_reads", "parse_read_reply", "write_request"]

_READ = "/nidaqmx_grpc.NiDAQmx/ReadAnalogF64"
_WRITE = "/nidaqmx_grpc.NiDAQmx/WriteAnalogF64"
#: field numbers: ReadAnalogF64Response {status 1, read_array 2, samps_per_chan_read 3},
#: WriteAnalogF64Request {..., write_array 7}
_R_STATUS, _R_ARRAY, _R_SAMPS = 1, 2, 3
_W_ARRAY = 7
_VARINT, _I64, _LEN, _I32 = 0, 1, 2, 5


@dataclass
class ReadReply:
    """A ``ReadAnalogF64Response`` with its samples as one float64 array."""

    status: int
    read_array: np.ndarray
    samps_per_chan_read: int


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        b = data[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        if b < 0x80:
            return value, pos
        shift += 7
        if shift > 63:
            raise ValueError("a protobuf varint longer than 10 bytes")


def _int32(value: int) -> int:
    """A varint as the int32 it encodes (negative values are sent as 64-bit two's complement)."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value >= 1 << 31 else value


def _varint_bytes(value: int) -> bytes:
    out = bytearray()
    while value >= 0x80:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def parse_read_reply(data: bytes) -> ReadReply:
    """A ``ReadAnalogF64Response`` from its wire bytes; the samples a view of ``data``."""
    status = samps = 0
    parts: list[np.ndarray] = []
    loose: list[float] = []  # a sender that did not pack (allowed): one value per field
    pos, end = 0, len(data)
    while pos < end:
        key, pos = _varint(data, pos)
        field, wire = key >> 3, key & 7
        if wire == _VARINT:
            value, pos = _varint(data, pos)
            if field == _R_STATUS:
                status = _int32(value)
            elif field == _R_SAMPS:
                samps = _int32(value)
        elif wire == _LEN:
            size, pos = _varint(data, pos)
            if pos + size > end:
                raise ValueError("ReadAnalogF64 reply: a field runs past the message's end")
            if field == _R_ARRAY:
                if size % 8:
                    raise ValueError(f"ReadAnalogF64 reply: {size} bytes of samples is not a "
                                     "whole number of float64 values")
                parts.append(np.frombuffer(data, "<f8", size // 8, pos))
            pos += size
        elif wire == _I64:
            if field == _R_ARRAY:
                loose.append(float(np.frombuffer(data, "<f8", 1, pos)[0]))
            pos += 8
        elif wire == _I32:
            pos += 4
        else:
            raise ValueError(f"ReadAnalogF64 reply: unknown wire type {wire}")
    if loose:
        parts.append(np.array(loose))
    array = parts[0] if len(parts) == 1 else (
        np.concatenate(parts) if parts else np.zeros(0))
    return ReadReply(status, array.astype(np.float64, copy=False), samps)


def write_request(head: bytes, data: np.ndarray) -> bytes:
    """A ``WriteAnalogF64Request``'s wire bytes: ``head`` (its other fields, serialised) and
    ``data``'s samples in C order as the packed ``write_array``."""
    payload = np.ascontiguousarray(data, dtype="<f8").tobytes()
    return (head + _varint_bytes(_W_ARRAY << 3 | _LEN) + _varint_bytes(len(payload))
            + payload)


def _grpc_interpreter(task: Any) -> Any:
    """The task's gRPC interpreter, or None for the local driver."""
    from nidaqmx._grpc_interpreter import GrpcStubInterpreter

    interpreter = task._interpreter
    return interpreter if isinstance(interpreter, GrpcStubInterpreter) else None


def packed_reads(task: Any) -> None:
    """Give ``task``'s gRPC stub a ``ReadAnalogF64`` that keeps the samples packed (no-op for
    the local driver)."""
    interpreter = _grpc_interpreter(task)
    if interpreter is None:
        return
    from nidaqmx._stubs import nidaqmx_pb2

    channel = interpreter._grpc_options.grpc_channel
    interpreter._client.ReadAnalogF64 = channel.unary_unary(
        _READ, request_serializer=nidaqmx_pb2.ReadAnalogF64Request.SerializeToString,
        response_deserializer=parse_read_reply)


class PackedWriter:
    """``WriteAnalogF64`` on ``task`` with the samples sent as one packed array
    (`AnalogMultiChannelWriter.write_many_sample`'s call: grouped by channel, no auto-start).
    ``available``: False on the local driver (use nidaqmx's writer there)."""

    def __init__(self, task: Any) -> None:
        self._interpreter = _grpc_interpreter(task)
        self.available = self._interpreter is not None
        if not self.available:
            return
        from nidaqmx._stubs import nidaqmx_pb2
        from nidaqmx.constants import FillMode

        self._handle = task._handle
        self._request = nidaqmx_pb2.WriteAnalogF64Request
        self._layout = FillMode.GROUP_BY_CHANNEL.value
        self._reply = nidaqmx_pb2.WriteAnalogF64Response.FromString
        self._rpc = self._interpreter._grpc_options.grpc_channel.unary_unary(
            _WRITE, request_serializer=None, response_deserializer=self._reply)

    def write(self, data: np.ndarray, timeout: float) -> int:
        """Write ``data`` (n_channels, n); the samples per channel written."""
        head = self._request(task=self._handle, num_samps_per_chan=int(data.shape[1]),
                             auto_start=False, timeout=timeout,
                             data_layout_raw=self._layout).SerializeToString()
        reply = self._interpreter._invoke(self._rpc, write_request(head, data))
        return int(reply.samps_per_chan_written)
