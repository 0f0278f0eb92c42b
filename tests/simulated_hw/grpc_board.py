"""A nidaqmx task on a simulated board's gRPC channel."""

from __future__ import annotations

import grpc
import nidaqmx


def task_on(channel: grpc.Channel) -> nidaqmx.Task:
    return nidaqmx.Task(grpc_options=nidaqmx.GrpcSessionOptions(channel, ""))
