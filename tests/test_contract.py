"""The device contract: what every unit speaking the native protocol does, whatever is behind the port.

The same tests run on the simulated unit served on a pseudo-terminal, on the in-process ``sim://``
URL, and on a real unit when one is given (``pytest --imu-port /dev/ttyUSB0``, or
``--imu-port /dev/ttyUSB0@115200`` for another baud rate than 921600), as python-can runs one test
suite on its virtual bus and on hardware. A real unit must lie still during the run.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers import CommandRejected, Device, SerialDevice, open_device
from mocks import register_sim_url
from mocks.pty_server import PtyServer
from protocols import native

G = 9.80665


@pytest.fixture(params=["pty", "sim", "real"])
def port(request: pytest.FixtureRequest):
    if request.param == "pty":
        with PtyServer(seed=11, rate_hz=200) as server:
            yield server.port_path
    elif request.param == "sim":
        register_sim_url()
        yield "sim://?seed=11&rate=200"
    else:
        real = request.config.getoption("--imu-port")
        if not real:
            pytest.skip("no real unit given: run with --imu-port PORT to check one against the contract")
        yield real


def open_port(port: str) -> Device:
    """``PATH@BAUD`` opens a real port at that baud rate."""
    path, _, baud = port.rpartition("@") if "@" in port and "://" not in port else (port, "", "")
    return open_device(path, baudrate=int(baud)) if baud else open_device(port)


@pytest.fixture
def device(port: str):
    with open_port(port) as dev:
        yield dev


def collect(dev: Device, seconds: float) -> np.ndarray:
    batches = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        batches.append(dev.read(0.05))
    return np.concatenate(batches)


def nominal_rate(dev: Device) -> float:
    rate = dev.get_info()["rate_hz"]
    assert isinstance(rate, int | float) and rate > 0
    return float(rate)


def test_identifies_itself(device: Device) -> None:
    info = device.get_info()
    for key in ("serial", "model", "firmware"):
        assert isinstance(info[key], str) and info[key]
    assert isinstance(info["rate_hz"], int | float) and info["rate_hz"] > 0
    assert device.info == info


def test_streams_in_order_at_its_rate_on_the_device_clock(device: Device) -> None:
    rate = nominal_rate(device)
    device.start()
    s = collect(device, 1.2)
    assert len(s) >= 0.8 * rate
    assert np.all((np.diff(s["seq"].astype(np.int64)) % 2**32) == 1)
    assert np.all(np.diff(s["t_us"].astype(np.int64)) > 0)
    assert np.median(np.diff(s["t_us"])) * 1e-6 == pytest.approx(1 / rate, rel=0.02)
    stats = device.stats
    assert stats.rate_hz == pytest.approx(rate, rel=0.02)
    assert stats.errors == 0 and stats.lost == 0 and stats.garbage_bytes == 0


def test_at_rest_reads_gravity_and_no_rotation(device: Device) -> None:
    device.start()
    s = collect(device, 0.6)
    assert len(s) > 10
    assert np.linalg.norm(s["acc"].mean(axis=0)) == pytest.approx(G, rel=0.1)
    assert np.linalg.norm(s["gyro"].mean(axis=0)) < 0.2  # rad/s: biases only
    assert np.all(np.isfinite(s["temp"])) and -40 <= float(np.median(s["temp"])) <= 125


def test_set_rate_changes_the_rate_and_is_reported(device: Device) -> None:
    original = nominal_rate(device)
    new = 100 if original != 100 else 50
    try:
        device.start()
        device.set_rate(new)
        assert nominal_rate(device) == new
        collect(device, 0.3)  # samples from before the change
        s = collect(device, 1.0)
        assert np.median(np.diff(s["t_us"])) * 1e-6 == pytest.approx(1 / new, rel=0.02)
    finally:
        device.set_rate(int(original))


def test_stop_silences_and_start_resumes(device: Device) -> None:
    device.start()
    assert len(collect(device, 0.3)) > 0
    device.stop()
    collect(device, 0.2)  # frames already on the way
    try:
        assert len(collect(device, 0.5)) == 0
    finally:
        device.start()
    assert len(collect(device, 0.5)) > 0


def test_unknown_command_and_bad_argument_are_refused_with_their_status(device: Device) -> None:
    assert isinstance(device, SerialDevice)
    with pytest.raises(CommandRejected) as unknown:
        device.command(0x1F)
    assert unknown.value.status == native.ACK_UNKNOWN
    with pytest.raises(CommandRejected) as bad:
        device.command(native.SET_RATE, b"\x01")  # the rate needs two bytes
    assert bad.value.status == native.ACK_BAD_ARGUMENT


def test_commands_while_streaming_lose_no_sample(device: Device) -> None:
    device.start()
    collect(device, 0.2)
    for _ in range(5):
        device.get_info()
        collect(device, 0.05)
    s = collect(device, 0.2)
    stats = device.stats
    assert len(s) > 0 and stats.lost == 0 and stats.errors == 0


def test_close_releases_the_port(port: str) -> None:
    first = open_port(port)
    first.close()
    with open_port(port) as again:
        again.start()
        assert len(collect(again, 0.5)) > 0
