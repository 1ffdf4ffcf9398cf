"""The polled port (a ``Device`` without a reader thread) keeps the device contract, over a real pty.

The contract's tests (``test_contract.py``) run here on :class:`drivers.polled_port.PolledPort`
against the simulated unit; the rest is what only the polled port does: reading without waiting,
commands answered through later reads, and a vanished port's samples delivered before its error.
"""

from __future__ import annotations

import select
import time
from collections.abc import Iterator

import numpy as np
import pytest
import test_contract as contract

from drivers import CommandRejected, CommandUnsupported, PortBusy, PortFlooding, PortLost
from drivers.polled_port import PolledPort
from mocks.device import SimDevice
from mocks.pty_fleet import FleetUnit, PtyFleet
from mocks.pty_server import PtyServer
from protocols import native


@pytest.fixture
def device() -> Iterator[PolledPort]:
    with PtyServer(seed=11, rate_hz=200) as server, PolledPort(server.port_path) as dev:
        yield dev


# The contract's tests, collected here with this module's ``device``.
test_identifies_itself = contract.test_identifies_itself
test_streams_in_order_at_its_rate_on_the_device_clock = (
    contract.test_streams_in_order_at_its_rate_on_the_device_clock)
test_at_rest_reads_gravity_and_no_rotation = contract.test_at_rest_reads_gravity_and_no_rotation
test_set_rate_changes_the_rate_and_is_reported = contract.test_set_rate_changes_the_rate_and_is_reported
test_stop_silences_and_start_resumes = contract.test_stop_silences_and_start_resumes
test_commands_while_streaming_lose_no_sample = contract.test_commands_while_streaming_lose_no_sample


def test_refused_commands_keep_their_status(device: PolledPort) -> None:
    with pytest.raises(CommandRejected) as unknown:
        device.command(0x1F)
    assert unknown.value.status == native.ACK_UNKNOWN
    with pytest.raises(CommandRejected) as bad:
        device.command(native.SET_RATE, b"\x01")
    assert bad.value.status == native.ACK_BAD_ARGUMENT


def test_send_returns_at_once_and_the_answer_comes_with_later_reads(device: PolledPort) -> None:
    mark = device.message_count
    device.send(native.GET_INFO)
    assert device.answer_since(native.GET_INFO, mark) is None  # nothing read yet
    deadline = time.monotonic() + 2.0
    while device.answer_since(native.GET_INFO, mark) is None and time.monotonic() < deadline:
        device.read(0.05)
    assert device.info["serial"] == "SIM-000011"


def test_the_port_is_held_exclusively_until_closed() -> None:
    with PtyServer(seed=3, rate_hz=200) as server:
        first = PolledPort(server.port_path)
        with pytest.raises(PortBusy):
            PolledPort(server.port_path)
        first.close()
        with PolledPort(server.port_path) as again:
            assert len(contract.collect(again, 0.3)) > 0


def test_a_vanished_port_gives_its_samples_then_its_error() -> None:
    unit = FleetUnit(SimDevice(seed=4, rate_hz=200), 2.0, "vanish", vanish_after_s=0.5)
    with PtyFleet([unit]) as fleet, PolledPort(fleet.ports[0]) as dev:
        dev.send(native.GET_INFO)  # the fleet streams from the host's first word
        got = []
        with pytest.raises(PortLost, match="went away"):
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline:
                got.append(dev.read(0.05))
        sent = fleet.stats[0].samples_sent
    samples = np.concatenate(got)
    assert 0 < len(samples) <= sent
    assert np.all(np.diff(samples["seq"].astype(np.int64)) == 1)
    assert dev.failed is not None


def test_a_protocol_without_commands_says_so() -> None:
    with PtyServer(seed=5, rate_hz=200) as server, PolledPort(server.port_path, protocol="xsens") as dev:
        with pytest.raises(CommandUnsupported, match="xsens protocol has no GET_INFO"):
            dev.send(native.GET_INFO)


def test_a_flooding_port_returns_at_once_and_is_dropped_once_it_falls_behind() -> None:
    # Native headers announcing the longest payload, as fast as the pty takes them: each byte costs a
    # CRC over a frame. A read takes a bounded share (it read and decoded the flood whole before: a
    # read_now of 29.8 s in the audit), and the port is dropped once its undecoded bytes pile up.
    flood = FleetUnit(SimDevice(seed=3, rate_hz=200), 10.0, "flood")
    with PtyFleet([flood]) as fleet, PolledPort(fleet.ports[0]) as port:
        port.send(native.GET_INFO)  # the fleet's units stream once the host speaks
        longest = 0.0
        deadline = time.monotonic() + 30
        with pytest.raises(PortFlooding, match="sends faster than the station can decode"):
            while time.monotonic() < deadline:
                began = time.monotonic()
                try:
                    port.read_now()
                finally:
                    longest = max(longest, time.monotonic() - began)
                select.select([port.fileno()], [], [], 0.02)
    assert longest < 0.3, f"a read took {longest:.2f} s"
