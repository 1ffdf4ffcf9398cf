"""The paced port (the TUI's and a factory run's device): the device contract over a real pty, reads
spaced a period apart that lose nothing, sharing between threads, and the commands of the threaded
device (RESTART).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import test_contract as contract

from drivers import PortLost, SerialDevice
from drivers.paced_port import READ_PERIOD_S, PacedPort, open_paced
from mocks import register_sim_url
from mocks.device import SimDevice
from mocks.pty_fleet import FleetUnit, PtyFleet
from mocks.pty_server import PtyServer
from protocols import native
from station.acquisition.turn_ons import restart_unit


@pytest.fixture
def device() -> Iterator[PacedPort]:
    with PtyServer(seed=12, rate_hz=200) as server, PacedPort(server.port_path) as dev:
        yield dev


# The contract's tests, collected here with this module's ``device``.
test_identifies_itself = contract.test_identifies_itself
test_streams_in_order_at_its_rate_on_the_device_clock = (
    contract.test_streams_in_order_at_its_rate_on_the_device_clock)
test_set_rate_changes_the_rate_and_is_reported = contract.test_set_rate_changes_the_rate_and_is_reported
test_stop_silences_and_start_resumes = contract.test_stop_silences_and_start_resumes
test_commands_while_streaming_lose_no_sample = contract.test_commands_while_streaming_lose_no_sample


def test_reads_come_a_period_apart_in_batches_and_lose_nothing() -> None:
    # The fleet writes every frame as it is due (1 ms at 1 kHz), as a unit on a USB link does.
    unit = FleetUnit(SimDevice(seed=13, rate_hz=1000), 3.0)
    with PtyFleet([unit], tick_s=0.001) as fleet, PacedPort(fleet.ports[0]) as dev:
        dev.get_info()  # the fleet streams from the host's first word
        batches = []
        start = time.monotonic()
        while time.monotonic() - start < 1.0:
            batch = dev.read(0.1)
            if len(batch):
                batches.append(batch)
        elapsed = time.monotonic() - start
    assert len(batches) <= elapsed / READ_PERIOD_S + 2  # not one read per arrival (1000 a second)
    assert np.mean([len(b) for b in batches]) >= 10
    seq = np.concatenate(batches)["seq"].astype(np.int64)
    assert np.all(np.diff(seq) == 1) and len(seq) >= 800


def test_a_read_without_time_to_wait_returns_at_once(device: PacedPort) -> None:
    device.read(0.1)
    start = time.monotonic()
    device.read(0)
    assert time.monotonic() - start < READ_PERIOD_S / 2


def test_another_thread_may_ask_and_command_while_one_reads(device: PacedPort) -> None:
    got: list[np.ndarray] = []
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            got.append(device.read(0.05))

    thread = threading.Thread(target=reader)
    thread.start()
    try:
        for _ in range(20):
            assert device.stats.samples >= 0
            assert device.get_info()["serial"] == "SIM-000012"
    finally:
        stop.set()
        thread.join()
    seq = np.concatenate(got)["seq"].astype(np.int64)
    assert len(seq) > 0 and np.all(np.diff(seq) == 1)


def test_restart_is_sent_once_and_the_unit_starts_again() -> None:
    sim = SimDevice(seed=14, rate_hz=200)
    with PtyServer(sim) as server, PacedPort(server.port_path) as dev:
        dev.get_info()
        dev.restart()
        assert sim.restarts == 1
        # the turn-ons restart any Device through the interface, this one as the threaded one
        assert restart_unit(dev) and sim.restarts == 2


def test_a_rate_that_does_not_fit_the_command_is_refused(device: PacedPort) -> None:
    with pytest.raises(Exception, match="does not fit SET_RATE") as refused:
        device.set_rate(70_000)
    assert getattr(refused.value, "status", None) == native.ACK_BAD_ARGUMENT


def test_a_url_is_opened_with_the_threaded_device_a_path_paced() -> None:
    register_sim_url()
    url = open_paced("sim://?seed=15&rate=100")
    try:
        assert type(url) is SerialDevice
    finally:
        url.close()
    with PtyServer(seed=15, rate_hz=100) as server:
        path = open_paced(server.port_path)
        try:
            assert type(path) is PacedPort
        finally:
            path.close()


def test_a_vanished_port_gives_its_samples_then_its_error() -> None:
    unit = FleetUnit(SimDevice(seed=16, rate_hz=200), 2.0, "vanish", vanish_after_s=0.5)
    with PtyFleet([unit]) as fleet, PacedPort(fleet.ports[0]) as dev:
        dev.send(native.GET_INFO)
        got = []
        with pytest.raises(PortLost, match="went away"):
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline:
                got.append(dev.read(0.05))
    seq = np.concatenate(got)["seq"].astype(np.int64)
    assert len(seq) > 0 and np.all(np.diff(seq) == 1)


def test_the_link_statistics_stay_live_while_nobody_reads_and_the_wait_is_bounded() -> None:
    with PtyServer(seed=17, rate_hz=1000) as server, \
            PacedPort(server.port_path, max_buffered_samples=300) as dev:
        dev.get_info()
        counts = []
        for _ in range(6):  # as the TUI's connect screen asks, twice a second
            time.sleep(0.25)
            counts.append(dev.stats.samples)
        assert all(b > a for a, b in zip(counts, counts[1:], strict=False))
        stats = dev.stats
        assert stats.overflow_drops > 0 and stats.lost == 0  # dropped here, counted; none lost on the link
        kept = dev.read(0)
        assert 0 < len(kept) <= 300
