"""The packed AI read and AO write (`daq.nidaqmx_packed`) against nidaqmx's own protobuf
classes: the same messages on the wire, the samples bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from nidaqmx._stubs import nidaqmx_pb2

from daq.nidaqmx_packed import parse_read_reply, write_request


def test_a_read_reply_parses_as_protobuf_reads_it():
    rng = np.random.default_rng(5)
    samples = rng.normal(scale=3.0, size=14 * 100)
    wire = nidaqmx_pb2.ReadAnalogF64Response(status=-200279, read_array=samples,
                                             samps_per_chan_read=100).SerializeToString()
    reply = parse_read_reply(wire)
    assert reply.status == -200279 and reply.samps_per_chan_read == 100
    np.testing.assert_array_equal(reply.read_array, samples)  # bit for bit
    assert reply.read_array.dtype == np.float64


def test_an_empty_reply_and_unpacked_samples_parse():
    empty = parse_read_reply(nidaqmx_pb2.ReadAnalogF64Response(status=0).SerializeToString())
    assert (empty.status, empty.samps_per_chan_read, empty.read_array.size) == (0, 0, 0)
    # a sender that does not pack writes field 2 once per value (wire type 1): allowed
    values = np.array([1.5, -2.25, 3e-9])
    unpacked = b"".join(bytes([2 << 3 | 1]) + v.tobytes() for v in values.astype("<f8"))
    reply = parse_read_reply(unpacked + bytes([3 << 3, 3]))
    np.testing.assert_array_equal(reply.read_array, values)
    assert reply.samps_per_chan_read == 3


def test_a_truncated_reply_is_refused():
    wire = nidaqmx_pb2.ReadAnalogF64Response(read_array=np.ones(10)).SerializeToString()
    with pytest.raises(ValueError, match="past the message's end"):
        parse_read_reply(wire[:-5])


def test_a_write_request_is_the_package_s_message():
    rng = np.random.default_rng(6)
    data = rng.normal(size=(2, 3000))
    head = nidaqmx_pb2.WriteAnalogF64Request(num_samps_per_chan=3000, auto_start=False,
                                             timeout=10.0, data_layout_raw=0)
    parsed = nidaqmx_pb2.WriteAnalogF64Request.FromString(
        write_request(head.SerializeToString(), data))
    expected = nidaqmx_pb2.WriteAnalogF64Request(num_samps_per_chan=3000, auto_start=False,
                                                 timeout=10.0, data_layout_raw=0,
                                                 write_array=data.flat)
    assert parsed == expected
    np.testing.assert_array_equal(np.array(parsed.write_array), data.ravel())  # channel by channel
