"""Other protocols over real pseudo-terminals, through pyserial and the driver's reader thread:
the real Xsens captures replayed in ragged chunks, and the simulated unit speaking each format."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
from device_helpers import read_samples
from test_proto_xsens import read_golden, xyz

from drivers import open_device
from mocks.device import SimDevice
from mocks.encoders_extra import DECODER_OF, EXTRA_ENCODERS
from mocks.pty_server import PtyServer
from mocks.raw_pty import open_raw_pty


class ReplayPty:
    """A raw pty whose master end the test writes recorded bytes into."""

    def __init__(self) -> None:
        self.master, self.slave, self.path = open_raw_pty()

    def replay(self, data: bytes, seed: int, max_chunk: int = 300) -> None:
        """Write ``data`` in random chunks with short pauses, so the reader sees ragged reads."""
        rng = np.random.default_rng(seed)
        pos = 0
        while pos < len(data):
            n = int(rng.integers(1, max_chunk))
            view = memoryview(data[pos : pos + n])
            while view:
                view = view[os.write(self.master, view):]
            pos += n
            time.sleep(float(rng.uniform(0, 0.002)))

    def close(self) -> None:
        for fd in (self.master, self.slave):
            os.close(fd)


@pytest.mark.parametrize("folder", ["1", "2", "3"])
@pytest.mark.parametrize("protocol", ["xsens", "auto"])
def test_real_xsens_capture_through_a_pty_gives_every_golden_sample(reference_data: Path, folder: str,
                                                                     protocol: str) -> None:
    base = reference_data / "xsens-mtdata2" / folder
    inertial = [b for b in read_golden(base / "output.golden") if "Acceleration" in b]
    pty = ReplayPty()
    try:
        with open_device(pty.path, protocol=protocol) as dev:
            pty.replay((base / "output.bin").read_bytes(), seed=int(folder))
            samples = read_samples(dev, len(inertial), timeout=10.0)
            stats = dev.stats
    finally:
        pty.close()
    assert len(samples) == len(inertial)
    acc = np.array([xyz(b["Acceleration"]) for b in inertial], np.float32)
    gyro = np.array([xyz(b["RateOfTurn"]) for b in inertial], np.float32)
    np.testing.assert_allclose(samples["acc"], acc, rtol=2e-7, atol=1e-9)
    np.testing.assert_allclose(samples["gyro"], gyro, rtol=2e-7, atol=1e-9)
    assert samples["t_us"].tolist() == [int(b["SampleTimeFine"][0]) * 100 for b in inertial]
    # seq is the packet counter: the packets without inertial data (GNSS-only) are its only gaps,
    # and the link counts them as skipped, not lost.
    counters = [int(b["PacketCounter"][0]) for b in inertial]
    gnss_only = counters[-1] - counters[0] + 1 - len(inertial)
    assert stats.errors == 0 and stats.lost == 0 and stats.seq_skipped == gnss_only == 4


@pytest.mark.parametrize("encoder", sorted(EXTRA_ENCODERS))
def test_simulated_unit_speaking_each_format_is_read_by_its_decoder_and_by_auto(encoder: str) -> None:
    atol = {"motioncal": 2e-3, "vnymr": 5e-4, "mavlink-scaled": 5e-3, "mavlink-raw": 5e-3}.get(encoder, 1e-5)
    for protocol in (DECODER_OF[encoder], "auto"):
        device = SimDevice(seed=4, rate_hz=200, encoder=encoder)
        with PtyServer(device, record=True) as server:
            with open_device(server.port_path, protocol=protocol) as dev:
                got = read_samples(dev, 60, timeout=10.0)
            sent = server.sent()
        assert len(got) >= 60, (encoder, protocol)
        # The host starts listening mid-stream: find its first sample among those sent, then
        # every later one must be the next sent, with the values the format can carry.
        first = int(np.argmin(np.abs(sent["acc"] - got["acc"][0]).sum(axis=1)))
        ref = sent[first : first + len(got)]
        np.testing.assert_allclose(got["acc"], ref["acc"], atol=atol, rtol=1e-6)
        np.testing.assert_allclose(got["gyro"], ref["gyro"], atol=atol, rtol=1e-6)
        if encoder not in ("motioncal", "vnymr"):  # the formats with a device clock
            assert np.abs(got["t_us"].astype(np.int64) - ref["t_us"].astype(np.int64)).max() <= 1000
