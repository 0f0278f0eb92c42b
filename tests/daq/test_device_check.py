"""`daq.device_check` in process against the simulated device server, through nidaqmx: what the
device reports about itself, and the backend handing a map's terminal configuration to DAQmx."""

from __future__ import annotations

import pytest

from daq.channels import TerminalConfig, default_channel_map
from daq.device_check import DeviceNotFoundError, LiveReader, check_map, read_inventory
from daq.errors import INVALID_ATTRIBUTE_VALUE, DaqError
from daq.nidaqmx_session import NidaqmxSession
from tests.daq.conftest import on_server


def test_inventory_is_what_the_board_offers(fast_server):
    session = NidaqmxSession(fast_server.address)
    try:
        inv = read_inventory(session, "dev1", ["Dev1/ai0", "Dev1/ai3", "Dev1/ai99"])
        assert inv.product == "PXIe-6358"
        assert inv.ai == tuple(f"Dev1/ai{i}" for i in range(16))
        assert inv.ao == ("Dev1/ao0", "Dev1/ao1")
        assert inv.lines == tuple(f"Dev1/port0/line{i}" for i in range(8))
        assert inv.ai_ranges_v == ((-1.0, 1.0), (-2.0, 2.0), (-5.0, 5.0), (-10.0, 10.0))
        assert inv.ao_ranges_v == ((-5.0, 5.0), (-10.0, 10.0))
        assert inv.ai_terminal_configs == {
            "Dev1/ai0": frozenset({TerminalConfig.DIFFERENTIAL}),
            "Dev1/ai3": frozenset({TerminalConfig.DIFFERENTIAL})}
        assert check_map(default_channel_map(), inv) == []
        with pytest.raises(DeviceNotFoundError) as err:
            read_inventory(session, "Dev7")
        assert err.value.present == ("Dev1",)
    finally:
        session.close()


def test_live_reader_reads_the_rig_at_rest(fast_server):
    cm = on_server(fast_server)
    session = NidaqmxSession(fast_server.address)
    try:
        with LiveReader(cm, session) as reader:
            values = reader.read(0.05)
        assert values.samples == 500
        t_oil = cm.ai_index("t_oil")
        assert values.mean[t_oil] == pytest.approx(24.0, abs=0.01)  # the rig's oil, degC
        assert values.mean_v[t_oil] == pytest.approx(0.24, abs=1e-4)  # 10 mV/degC
        fx = cm.ai_index("fx")
        assert abs(values.mean[fx]) < 0.02 and 0.01 < values.std[fx] < 0.1  # N, noise only
    finally:
        session.close()


def test_the_backend_hands_the_terminal_configuration_to_daqmx(fast_server, backend):
    data = on_server(fast_server).model_dump(mode="json")
    data["ai"][4]["terminal_config"] = "nrse"
    cm = type(on_server(fast_server)).model_validate(data)
    with pytest.raises(DaqError) as err:
        backend.configure(cm)
    assert err.value.code == INVALID_ATTRIBUTE_VALUE
    assert "AI channel y1 on Dev1/ai4" in str(err.value) and "AI.TermCfg" in str(err.value)
    data["ai"][4]["terminal_config"] = "differential"
    backend.configure(type(cm).model_validate(data))  # the one the board has
