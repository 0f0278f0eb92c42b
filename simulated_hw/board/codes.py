"""NI-DAQmx status codes, enum values and attribute ids the simulated board speaks (the same
numbers as ``nidaqmx.error_codes`` and ``nidaqmx.constants``), and its error builder."""

from __future__ import annotations

from daq.errors import (
    CANT_RESET_EXPIRED_WATCHDOG,
    DEVICE_NOT_FOUND,
    INPUT_BUFFER_OVERWRITTEN,
    INVALID_ATTRIBUTE_VALUE,
    OUTPUT_UNDERFLOW,
    READ_TIMEOUT,
    RESOURCE_RESERVED,
    SAMPLE_RATE_TOO_HIGH,
    WRITE_FAILED_WATCHDOG_EXPIRED,
    DaqError,
    error_for_code,
)

# --- NI-DAQmx codes and constants the server uses (values as in nidaqmx.error_codes/constants) --
UNKNOWN_ERROR = -200000  # no better code; the message says what happened
SAMPLE_RATE_TOO_LOW = -200331
INVALID_TASK = -200088
DUPLICATE_TASK = -200089
PHYSICAL_CHAN_DOES_NOT_EXIST = -200170
REPEATED_PHYSICAL_CHAN = -200371
READ_BUFFER_TOO_SMALL = -200229
SAMPLES_CAN_NOT_YET_BE_WRITTEN = -200292
INVALID_AO_DATA_WRITE = -200561
TASK_NOT_RUNNING = -200475  # CANNOT_PERFORM_OP_WHEN_TASK_NOT_RUNNING
NO_CHANS_IN_TASK = -200478
NO_CHANS_OF_GIVEN_TYPE = -200611
INVALID_ROUTING_SOURCE = -200040
WRITE_NUM_CHANS_MISMATCH = -200524
ATTR_INCONSISTENT = -200128  # ATTRIBUTE_INCONSISTENT_ACROSS_REPEATED_PHYSICAL_CHANNELS
OUTPUT_BUFFER_EMPTY = -200462
SAMPLES_WILL_NEVER_BE_AVAILABLE = -200278
WAIT_UNTIL_DONE_NOT_DONE = -200560  # WAIT_UNTIL_DONE_DOES_NOT_INDICATE_DONE
WATCHDOG_TIMEOUT_OUT_OF_RANGE = -200668  # WATCHDOG_TIMEOUT_OUT_OF_RANGE_AND_NOT_SPECIAL_VAL
ACTION_NOT_SUPPORTED_TASK_NOT_WATCHDOG = -200635
DEVICE_DOES_NOT_SUPPORT_THIS_OPERATION = -201380
PHYS_CHAN_MEAS_TYPE = -200431  # the physical channel does not support the measurement type
SIGNAL_EVENTS_NOT_SUPPORTED = -200982
EVERY_N_ACQ_NOT_SUPPORTED = -200981  # EVERY_N_SAMPLES_ACQ_INTO_BUFFER_EVENT_NOT_SUPPORTED...
EVERY_N_XFER_NOT_SUPPORTED = -200980  # EVERY_N_SAMPS_TRANSFERRED_FROM_BUFFER_EVENT_NOT_...

_ERROR_TEXT = {
    READ_TIMEOUT: "Wait Until Done did not indicate all samples were acquired/generated in the "
    "specified timeout: samples not yet available",
    INPUT_BUFFER_OVERWRITTEN: "The application is not able to keep up with the hardware "
    "acquisition: attempted to read samples that are no longer available",
    OUTPUT_UNDERFLOW: "Generation stopped to prevent the regeneration of old samples: the "
    "application is not able to write samples to the buffer fast enough",
    SAMPLE_RATE_TOO_HIGH: "Sample clock rate is higher than the maximum the device supports",
    SAMPLE_RATE_TOO_LOW: "Sample clock rate is lower than the minimum the device supports",
    DEVICE_NOT_FOUND: "Device identifier is invalid",
    PHYSICAL_CHAN_DOES_NOT_EXIST: "Physical channel specified does not exist on this device",
    RESOURCE_RESERVED: "The specified resource is reserved",
    INVALID_TASK: "Task specified is invalid or does not exist",
    DUPLICATE_TASK: "Task cannot be created because a task with this name already exists",
    INVALID_AO_DATA_WRITE: "Data written is outside the range of the output channel",
    OUTPUT_BUFFER_EMPTY: "Generation cannot be started because the output buffer is empty",
    SAMPLES_WILL_NEVER_BE_AVAILABLE: "Attempted to read samples that will never be available",
    WAIT_UNTIL_DONE_NOT_DONE: "Wait Until Done did not indicate all samples were acquired or "
    "generated in the specified timeout",
    CANT_RESET_EXPIRED_WATCHDOG: "Watchdog timer cannot be reset because it has expired; "
    "clear the expiration first",
    WRITE_FAILED_WATCHDOG_EXPIRED: "Write failed because the watchdog timer expired",
    DEVICE_DOES_NOT_SUPPORT_THIS_OPERATION: "The device does not support this operation",
    PHYS_CHAN_MEAS_TYPE: "Measurement type not supported by the physical channel",
    SIGNAL_EVENTS_NOT_SUPPORTED: "Signal events are not supported by the device",
}

# channel types, measurement/output types, enums
CHAN_AI, CHAN_AO, CHAN_DI, CHAN_DO = 10100, 10102, 10151, 10153
MEAS_VOLTAGE = 10322
REGEN_ALLOW, REGEN_DONT_ALLOW = 10097, 10158
MODE_FINITE, MODE_CONTINUOUS = 10178, 10123
FILL_GROUP_BY_CHANNEL = 0
LINES_PER_CHAN_ALL = 1  # LineGrouping.CHAN_FOR_ALL_LINES
INIT_AUTO, INIT_NEW, INIT_ATTACH = 0, 1, 2
IDLE_ZERO_VOLTS, IDLE_HIGH_IMPEDANCE, IDLE_MAINTAIN = 12526, 12527, 12528  # AOIdleOutputBehavior
WDT_RESET_TIMER, WDT_CLEAR_EXPIRATION = 0, 1  # WDTTaskAction
LEVEL_HIGH, LEVEL_LOW, LEVEL_TRISTATE, NO_CHANGE = 10192, 10214, 10310, 10160  # Level
WDT_AO_VOLTAGE = 10322  # WatchdogAOExpirState.VOLTAGE

# attribute ids (nidaqmx task/_in_stream.py, _out_stream.py, _timing.py, system/_system.py)
ATTR_DRIVER_MAJOR, ATTR_DRIVER_MINOR, ATTR_DRIVER_UPDATE = 0x1272, 0x1923, 0x2F22
ATTR_SYS_DEVICES = 0x193B
ATTR_TASK_NAME, ATTR_TASK_CHANNELS, ATTR_TASK_NUM_CHANS = 0x1276, 0x1273, 0x2181
ATTR_CHAN_TYPE, ATTR_AI_MEAS_TYPE, ATTR_AO_OUTPUT_TYPE = 0x187F, 0x0695, 0x1108
ATTR_READ_CHANNELS, ATTR_READ_NUM_CHANS, ATTR_READ_AVAIL = 0x1823, 0x217B, 0x1223
ATTR_READ_POS = 0x1221
ATTR_DI_BOOLS_PER_CHAN = 0x217C
ATTR_WRITE_NUM_CHANS, ATTR_DO_BOOLS_PER_CHAN = 0x217E, 0x217F
ATTR_WRITE_REGEN, ATTR_WRITE_GENERATED, ATTR_WRITE_SPACE = 0x1453, 0x192B, 0x1460
ATTR_SAMP_CLK_RATE = 0x1344
ATTR_WRITE_REL_TO, ATTR_WRITE_OFFSET = 0x190C, 0x190D  # out_stream.relative_to, .offset
WRITE_REL_FIRST_SAMPLE, WRITE_REL_CURR_POS = 10424, 10430  # WriteRelativeTo
ATTR_OUTPUT_ONBRD_BUF_SIZE = 0x230B  # out_stream.output_onbrd_buf_size (buffer attribute)
#: the PXIe-6358's AO FIFO [samples, shared by the task's channels]
AO_FIFO_SAMPLES = 8191
ATTR_INPUT_BUF_SIZE, ATTR_OUTPUT_BUF_SIZE = 0x186C, 0x186D
ATTR_READ_DEFAULT_N = 0x31E8  # DAQmx_DefaultNumberOfSamplesToRead (READ_ALL_AVAILABLE)
ATTR_AO_IDLE_OUTPUT = 0x2240  # ao_idle_output_behavior (task/channels/_ao_channel.py)
ATTR_WDT_EXPIRED, ATTR_WDT_TIMEOUT = 0x21A8, 0x21A9  # system/watchdog.py
ATTR_SAMP_QUANT_MODE, ATTR_SAMP_QUANT_N = 0x1300, 0x1310  # timing: sample mode, samples/chan

# device capabilities (nidaqmx system/device.py, system/physical_channel.py)
ATTR_DEV_PRODUCT_TYPE = 0x0631
ATTR_DEV_IS_SIMULATED = 0x22CA  # bool: an NI simulated device (this one is)
ATTR_DEV_AI_PHYSICAL_CHANS, ATTR_DEV_AO_PHYSICAL_CHANS = 0x231E, 0x231F
ATTR_DEV_DI_LINES, ATTR_DEV_DO_LINES = 0x2320, 0x2322
ATTR_DEV_AI_VOLTAGE_RNGS, ATTR_DEV_AO_VOLTAGE_RNGS = 0x2990, 0x299B  # [lo, hi, lo, hi, ...]
ATTR_PHYS_AI_TERM_CFGS = 0x2342  # bitfield: RSE 1, NRSE 2, DIFF 4, PSEUDO_DIFF 8
TERM_DEFAULT, TERM_RSE, TERM_NRSE, TERM_DIFF, TERM_PSEUDO_DIFF = -1, 10083, 10078, 10106, 12529
TERM_BITS = {TERM_RSE: 1, TERM_NRSE: 2, TERM_DIFF: 4, TERM_PSEUDO_DIFF: 8}
TERM_NAMES = {TERM_RSE: "RSE", TERM_NRSE: "NRSE", TERM_DIFF: "differential",
              TERM_PSEUDO_DIFF: "pseudodifferential"}
#: the PXIe-6358's AI input ranges (bipolar, +/- V), its AO ranges, and its AI terminal
#: configuration (simultaneous sampling: differential only), as NI's specifications give them
AI_RANGES_V = (1.0, 2.0, 5.0, 10.0)
AO_RANGES_V = (5.0, 10.0)
AI_TERM_CFGS = (TERM_DIFF,)

DRIVER_VERSION = (24, 8, 0)
SERVICE_NAME = "nidaqmx_grpc.NiDAQmx"


MAX_CHUNK = 100_000  # samples the rig runs in one go (bounds memory when a reader lags)


def terminal_config_error(cfg: int, physical: list[str], where: str) -> DaqError | None:
    """The error for an AI terminal configuration the device's channels do not allow (DAQmx
    -200077 naming the property, as the driver reports it), or None when it is allowed. One
    rule for the gRPC board and the simulated rig in process (`simulated_hw.backend`)."""
    if cfg in (TERM_DEFAULT, 0) or cfg in AI_TERM_CFGS:  # 0: a request that left it unset
        return None
    allowed = ", ".join(TERM_NAMES[c] for c in AI_TERM_CFGS)
    return daq_error(
        INVALID_ATTRIBUTE_VALUE,
        f"{where}: Requested value is not a supported value for this property. Property: "
        f"AI.TermCfg, requested value: {TERM_NAMES.get(cfg, cfg)}, possible values: {allowed} "
        f"(physical channel {', '.join(physical)})",
    )


def daq_error(code: int, message: str, samps_per_chan_read: int | None = None) -> DaqError:
    """Our typed error, with the sample count NI reports alongside a failed read."""
    err = error_for_code(message, code)
    err.samps_per_chan_read = samps_per_chan_read  # type: ignore[attr-defined]
    err.bare_message = message  # type: ignore[attr-defined]
    return err
