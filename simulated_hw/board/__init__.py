"""The simulated NI-DAQmx board behind `simulated_hw.grpc_server`: DAQmx codes, tasks, the device
and its clock, the gRPC servicer."""
