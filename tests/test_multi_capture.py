"""``imu-station capture`` with several ports: one process, one file per unit named by its serial.

Every unit is on a real pty: clean units are the project's simulator (``PtyServer``, which keeps
what it sent), failing ones come from ``PtyFleet`` (garbage, silence, a port that vanishes).
Files are read back and compared with what was sent, sample for sample.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from contextlib import nullcontext
from pathlib import Path

import h5py
import numpy as np
import pytest

from drivers.errors import CommandRejected, PortError
from drivers.polled_port import PolledPort
from mocks.device import SimDevice
from mocks.pty_fleet import FleetUnit, PtyFleet
from mocks.pty_server import PtyServer
from station.acquisition import recorder
from station.acquisition.capture import read_capture
from station.acquisition.capture_h5 import read_samples
from station.acquisition.multi_capture import capture_many, file_stem
from station.cli import main
from station.errors import OutputFileError

CLI = [str(Path(sys.executable).with_name("imu-station"))]
RATE_HZ = 200


def assert_same_samples(path: Path, sent: np.ndarray, rows: int) -> None:
    """The capture CSV at ``path`` holds ``rows`` samples: ``rows`` the unit sent in a row, from one of
    its first (pyserial empties the port's input as it opens it: the first frames may go there)."""
    got = read_capture(path)
    assert len(got) == rows
    k = int(np.searchsorted(sent["t_us"], round(got.t[0] * 1e6)))
    assert k <= 20, f"the capture starts {k} samples late"
    expected = sent[k : k + rows]
    np.testing.assert_array_equal(np.round(got.t * 1e6).astype(np.int64), expected["t_us"].astype(np.int64))
    np.testing.assert_array_equal(got.acc.astype(np.float32), expected["acc"])
    np.testing.assert_array_equal(got.gyro.astype(np.float32), expected["gyro"])


def test_units_recorded_by_serial_while_failing_units_are_reported(tmp_path: Path) -> None:
    failing = [FleetUnit(SimDevice(seed=20 + i, rate_hz=RATE_HZ), 3.0, mode, vanish_after_s=0.5)
               for i, mode in enumerate(("garbage", "silent", "vanish"))]
    out = tmp_path / "tray"
    with PtyServer(seed=11, rate_hz=RATE_HZ, record=True) as a, \
            PtyServer(seed=12, rate_hz=RATE_HZ, record=True) as b, PtyFleet(failing) as fleet:
        garbage, silent, vanish = fleet.ports
        ports = [a.port_path, garbage, b.port_path, silent, vanish]
        run = subprocess.run([*CLI, "capture", *(x for p in ports for x in ("--port", p)), "--duration", "1",
                              "-o", str(out)], capture_output=True, text=True, timeout=60)
        vanished = fleet.stats[2].samples_sent
    assert run.returncode == 3, run.stderr
    assert sorted(p.name for p in out.iterdir()) == ["SIM-000011.csv", "SIM-000012.csv", "SIM-000022.csv"]
    assert_same_samples(out / "SIM-000011.csv", a.sent(), RATE_HZ)
    assert_same_samples(out / "SIM-000012.csv", b.sent(), RATE_HZ)
    kept = len(read_capture(out / "SIM-000022.csv"))
    assert 0 < kept <= vanished
    errors = [line for line in run.stderr.splitlines() if line.startswith("imu-station capture: error:")]
    assert len(errors) == 3
    assert f"{garbage}: no sample arrived" in errors[0] and "not frames" in errors[0]
    assert f"{silent}: no sample arrived in 5 s (0 bytes read" in errors[1]
    assert f"{vanish}: the port went away" in errors[2]
    assert f"SIM-000011 ({a.port_path}): wrote {RATE_HZ} samples" in run.stdout
    assert "3 of 5 units have a file, 3 ended with an error" in run.stdout


def test_h5_files_and_a_serial_reported_twice(tmp_path: Path) -> None:
    # Two units that report one serial: the second file gets a suffix, and the outcome says so.
    with PtyServer(device=SimDevice(seed=5, rate_hz=RATE_HZ), record=True) as a, \
            PtyServer(device=SimDevice(seed=5, rate_hz=RATE_HZ), record=True) as b:
        outcomes = capture_many([a.port_path, b.port_path], tmp_path, fmt="h5", duration_s=0.5,
                                handle_sigint=False)
    assert [o.serial for o in outcomes] == ["SIM-000005", "SIM-000005"]
    assert [o.capture.path.name for o in outcomes if o.capture] == ["SIM-000005.h5", "SIM-000005-2.h5"]
    assert outcomes[0].note == ""
    assert f"also reported by {a.port_path}" in outcomes[1].note and "SIM-000005-2.h5" in outcomes[1].note
    for outcome, server in zip(outcomes, (a, b), strict=True):
        assert outcome.error is None and outcome.capture is not None
        got = read_samples(outcome.capture.path)
        assert len(got) == RATE_HZ // 2 == outcome.capture.rows
        sent = server.sent()
        k = int(np.searchsorted(sent["t_us"], got["t_us"][0]))
        assert k <= 20 and got.tobytes() == sent[k : k + len(got)].tobytes()


def test_rate_set_on_every_unit_and_a_refused_rate_fails_the_unit(tmp_path: Path) -> None:
    with PtyServer(seed=41, rate_hz=RATE_HZ) as a, PtyServer(seed=42, rate_hz=RATE_HZ) as b:
        outcomes = capture_many([a.port_path, b.port_path], tmp_path / "slow", fmt="h5", duration_s=0.5,
                                rate_hz=100, handle_sigint=False)
        refused = capture_many([a.port_path], tmp_path / "fast", duration_s=0.5, rate_hz=5000,
                               handle_sigint=False)
    for outcome in outcomes:
        assert outcome.error is None and outcome.capture is not None
        got = read_samples(outcome.capture.path)
        # Every row at the new rate: the samples before the ACK are not part of the capture.
        assert len(got) == 50 and set(np.diff(got["t_us"].astype(np.int64))) == {10_000}
        with h5py.File(outcome.capture.path) as f:
            assert json.loads(f.attrs["device"])["rate_hz"] == 100
    (outcome,) = refused
    assert isinstance(outcome.error, CommandRejected)
    assert "refused SET_RATE: bad argument" in str(outcome.error)
    assert "no file was written" in str(outcome.error)
    assert not (tmp_path / "fast" / "SIM-000041.csv").exists()


def test_a_full_disk_stops_the_capture_with_its_error(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    # The recorder's own disk-space guard, told that no disk has room: the writer thread's error
    # reaches the caller, and every port and file is closed on the way.
    monkeypatch.setattr(recorder, "MIN_FREE_BYTES", 1 << 62)
    with PtyServer(seed=51, rate_hz=RATE_HZ) as a, PtyServer(seed=52, rate_hz=RATE_HZ) as b:
        with pytest.raises(OutputFileError, match="the disk is almost full"):
            capture_many([a.port_path, b.port_path], tmp_path, duration_s=5, handle_sigint=False)
    assert list(tmp_path.iterdir()) == []  # no row was written: no file is left


def test_ctrl_c_keeps_every_sample_received(tmp_path: Path) -> None:
    with PtyServer(seed=31, rate_hz=RATE_HZ, record=True) as a, PtyServer(seed=32, rate_hz=RATE_HZ,
                                                                             record=True) as b:
        proc = subprocess.Popen([*CLI, "capture", "--port", a.port_path, "--port", b.port_path, "-o",
                                 str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 20
        while len(list(tmp_path.glob("*.csv"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=20)
        sent = {"SIM-000031": a.sent(), "SIM-000032": b.sent()}
    assert proc.returncode == 130, stderr
    assert "interrupted; the files keep every sample received" in stderr
    for serial, samples in sent.items():
        got = read_capture(tmp_path / f"{serial}.csv")
        # Every row is a sample sent, in order; the last ones sent may have been on the wire.
        assert RATE_HZ // 4 < len(got) <= len(samples)
        assert_same_samples(tmp_path / f"{serial}.csv", samples, len(got))
        assert f"wrote {len(got)} samples" in stdout


def test_usage_errors_of_several_ports(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a_file = tmp_path / "a.csv"
    a_file.write_text("")
    cases = [
        (["--port", "/dev/null", "--format", "h5", "-o", str(tmp_path / "x.h5")],
         "--format applies to several"),
        (["--port", "/dev/null", "--port", "/dev/zero", "--protocol", "auto", "-o", str(tmp_path)],
         "--protocol auto reads one port"),
        (["--port", "/dev/null", "--port", "/dev/zero", "-o", str(a_file)], "names a directory"),
    ]
    for argv, message in cases:
        assert main(["capture", *argv]) == 4
        assert message in capsys.readouterr().err


def test_a_url_has_no_descriptor_to_watch() -> None:
    with pytest.raises(PortError, match="a URL has no file descriptor"):
        PolledPort("loop://")


def test_file_stem_keeps_a_serial_inside_the_directory() -> None:
    assert file_stem("SIM-000001") == "SIM-000001"
    assert file_stem("../../etc/passwd") == "_.._etc_passwd"
    assert file_stem("a b/c\x1b") == "a_b_c_"
    assert file_stem("...") == "unit"


def test_a_flooding_unit_is_dropped_while_the_others_record_at_full_rate(tmp_path: Path) -> None:
    # A port that floods native headers announcing the longest payload costs the decoder a CRC over a
    # frame per byte: it gets a bounded share of each turn, and is dropped once it falls behind.
    flood = FleetUnit(SimDevice(seed=30, rate_hz=RATE_HZ), 10.0, "flood")
    duration_s = 3.0
    with PtyServer(seed=31, rate_hz=1000, record=True) as a, \
            PtyServer(seed=32, rate_hz=1000, record=True) as b, PtyFleet([flood]) as fleet:
        shown: list[float] = []  # when the loop showed the units' status: it runs every turn or so
        started = time.monotonic()
        def show(_: object) -> None:
            shown.append(time.monotonic())

        outcomes = capture_many([a.port_path, fleet.ports[0], b.port_path], tmp_path, duration_s=duration_s,
                                status=lambda ports, duration: nullcontext(show))
        took = time.monotonic() - started
        sent_a, sent_b = a.sent(), b.sent()
    healthy = [o for o in outcomes if o.port != fleet.ports[0]]
    for outcome, sent in zip(healthy, (sent_a, sent_b), strict=True):
        assert outcome.error is None, outcome.error
        assert outcome.capture is not None
        assert_same_samples(outcome.capture.path, sent, round(duration_s * 1000))
    flooded = next(o for o in outcomes if o.port == fleet.ports[0])
    assert flooded.error is not None and "faster than the station can decode" in str(flooded.error)
    assert took < duration_s + 10, f"the capture took {took:.1f} s"
    # The status shows every 0.25 s while the loop turns; a flood's decoding held it 0.8 s before.
    assert max(np.diff(shown)) < 0.7, f"the loop stalled {max(np.diff(shown)):.2f} s"
