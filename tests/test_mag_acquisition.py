"""The magnetometer on the wire and in the capture files: native IMU_MAG_SAMPLE, CSV mx/my/mz, HDF5 mag,
the recorder over a real pty."""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_drivers_serial import RawPty, make_samples

from drivers import open_device
from mocks.device import SimDevice
from mocks.mag_sessions import mag_capture, nine_axis_unit
from mocks.magnetometer import EarthField, MagTruth, mag_from_options
from mocks.protocol_sim import parse_sim_url
from mocks.pty_server import PtyServer
from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE, has_mag
from protocols.crc import crc16_ccitt_false
from protocols.mag_batches import join_batches, with_mag
from protocols.native import (
    IMU_MAG_SAMPLE,
    MAG_FRAME_SIZE,
    NativeDecoder,
    encode_frame,
    encode_samples,
)
from station.acquisition.capture import Capture, read_capture
from station.acquisition.capture_csv import CsvCaptureWriter, write_csv
from station.acquisition.capture_h5 import H5CaptureWriter, read_samples
from station.acquisition.recorder import record
from station.acquisition.runner import samples_to_capture
from station.errors import InputFileError


def _header(path: Path) -> str:
    """A capture CSV's header row, after its ``#`` metadata lines."""
    return next(line for line in path.read_text().splitlines() if not line.startswith("#"))


def make_mag_samples(n: int, first_seq: int = 0, seed: int = 0) -> np.ndarray:
    """Nine-axis records: the six-axis ones of the serial tests and a field of about 50 uT."""
    out = with_mag(make_samples(n, first_seq, seed)).copy()
    out["mag"] = np.random.default_rng(seed + 1).normal(0, 30, (n, 3))
    return out


# ---------------------------------------------------------------------------------- native 0x04


def test_mag_frame_layout_matches_spec() -> None:
    s = make_mag_samples(1)
    frame = encode_samples(s)
    assert len(frame) == MAG_FRAME_SIZE == 59
    assert frame[2] == IMU_MAG_SAMPLE and struct.unpack("<H", frame[3:5])[0] == 52
    seq, t_us, *vals = struct.unpack("<IQ10f", frame[5:57])
    assert seq == s["seq"][0] and t_us == s["t_us"][0]
    assert np.allclose(vals[7:], s["mag"][0]) and np.allclose(vals[:3], s["acc"][0])
    assert struct.unpack("<H", frame[57:])[0] == crc16_ccitt_false(frame[2:57])
    assert encode_frame(IMU_MAG_SAMPLE, frame[5:57]) == frame


@pytest.mark.parametrize("chunk", [1, 7, 59, 1000])
def test_mag_round_trip_in_any_chunking(chunk: int) -> None:
    sent = make_mag_samples(600)
    data = encode_samples(sent)
    dec = NativeDecoder()
    got = join_batches([dec.feed(data[i:i + chunk]).samples for i in range(0, len(data), chunk)])
    assert got.dtype == MAG_SAMPLE_DTYPE and got.tobytes() == sent.tobytes()
    assert dec.stats.samples == 600 and dec.stats.errors == 0


def test_mag_faults_cost_only_the_damaged_frame() -> None:
    sent = make_mag_samples(40)
    frames = [bytearray(encode_samples(sent[i:i + 1])) for i in range(40)]
    frames[5][20] ^= 0xFF  # bad CRC
    frames[12] = frames[12][:30]  # cut short by the next frame
    bad_len = bytearray(encode_frame(IMU_MAG_SAMPLE, bytes(48)))  # good CRC, wrong length
    data = b"".join(bytes(f) for f in frames[:20]) + b"\x00garbage" + bytes(bad_len) + \
        b"".join(bytes(f) for f in frames[20:])
    dec = NativeDecoder()
    got = join_batches([dec.feed(data).samples, dec.flush().samples])
    expected = np.delete(sent, [5, 12])
    assert got.tobytes() == expected.tobytes()
    assert dec.stats.crc_errors == 1 and dec.stats.truncated == 1 and dec.stats.bad_payloads == 1


def test_mixed_stream_counts_seq_alike_and_widens_six_axis_frames() -> None:
    six = make_samples(10)
    nine = make_mag_samples(10, first_seq=10)
    dec = NativeDecoder()
    first = dec.feed(encode_samples(six[:5])).samples
    assert first.dtype == SAMPLE_DTYPE  # no field seen yet: the fast 40-byte path's records
    rest = dec.feed(encode_samples(nine[:5]) + encode_samples(six[5:]) + encode_samples(nine[5:])).samples
    assert rest.dtype == MAG_SAMPLE_DTYPE
    assert list(rest["seq"]) == list(range(10, 15)) + list(range(5, 10)) + list(range(15, 20))
    assert np.isnan(rest["mag"][5:10]).all() and np.array_equal(rest["mag"][:5], nine["mag"][:5])
    assert dec.feed(b"").samples.dtype == MAG_SAMPLE_DTYPE  # sticky, even when empty


def test_join_batches_widens_and_skips_empty() -> None:
    six, nine = make_samples(3), make_mag_samples(2)
    joined = join_batches([six, np.zeros(0, SAMPLE_DTYPE), nine])
    assert joined.dtype == MAG_SAMPLE_DTYPE and len(joined) == 5 and np.isnan(joined["mag"][:3]).all()
    assert join_batches([six, six]).dtype == SAMPLE_DTYPE
    assert len(join_batches([])) == 0


# ---------------------------------------------------------------------------------- files


def _capture(n: int = 50) -> Capture:
    return samples_to_capture(make_mag_samples(n), np.array(["+z"] * n, dtype=object))


def test_csv_round_trip_keeps_the_field(tmp_path: Path) -> None:
    cap = _capture()
    cap.mag[3] = np.nan  # a sample without a field stays one
    write_csv(tmp_path / "c.csv", cap)
    header = _header(tmp_path / "c.csv").split(",")
    assert header[-4:] == ["mx", "my", "mz", "step"]
    back = read_capture(tmp_path / "c.csv")
    assert back.mag is not None and np.allclose(back.mag, cap.mag, equal_nan=True, rtol=1e-7)


def test_csv_without_mag_columns_has_none(tmp_path: Path) -> None:
    cap = samples_to_capture(make_samples(20))
    write_csv(tmp_path / "c.csv", cap)
    assert "mx" not in (tmp_path / "c.csv").read_text().splitlines()[0]
    assert read_capture(tmp_path / "c.csv").mag is None


def test_csv_with_some_mag_columns_is_refused_naming_the_missing_one(tmp_path: Path) -> None:
    path = tmp_path / "part.csv"
    path.write_text("t,ax,ay,az,gx,gy,gz,mx,mz\n0,0,0,9.8,0,0,0,20,40\n")
    with pytest.raises(InputFileError) as err:
        read_capture(path)
    message = str(err.value)
    assert "part.csv" in message and "my" in message and "line 1" in message and "all three" in message


def test_csv_bad_mag_value_names_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text("t,ax,ay,az,gx,gy,gz,mx,my,mz\n0,0,0,9.8,0,0,0,20,1,40\n0.01,0,0,9.8,0,0,0,20,x,40\n")
    with pytest.raises(InputFileError) as err:
        read_capture(path)
    assert "line 3" in str(err.value) and "my" in str(err.value)


def test_streaming_csv_header_follows_the_first_batch(tmp_path: Path) -> None:
    nine, six = make_mag_samples(20), make_samples(10, first_seq=20)
    w = CsvCaptureWriter(tmp_path / "s.csv")
    w.write(nine)
    w.write(six)  # a batch without a field: NaN there
    w.close()
    back = read_capture(tmp_path / "s.csv")
    assert back.mag is not None and np.allclose(back.mag[:20], nine["mag"], rtol=1e-7)
    assert np.isnan(back.mag[20:]).all()
    empty = CsvCaptureWriter(tmp_path / "e.csv")
    empty.close()
    assert _header(tmp_path / "e.csv") == "t,ax,ay,az,gx,gy,gz,temp"


@pytest.mark.parametrize("with_step", [False, True])
def test_a_field_that_comes_late_widens_the_csv_once(tmp_path: Path, with_step: bool) -> None:
    six, nine, more = make_samples(10), make_mag_samples(20, first_seq=10), make_mag_samples(5, first_seq=30)
    w = CsvCaptureWriter(tmp_path / "late.csv", with_step=with_step)
    w.write(six, ["pose a"] * 10 if with_step else None)
    w.write(nine, ["pose b"] * 20 if with_step else None)  # the first field: the rows so far get NaN
    w.write(more, ["pose b"] * 5 if with_step else None)
    w.close()
    assert w.rows == 35 and w.field_dropped == 0
    back = read_capture(tmp_path / "late.csv")
    assert len(back) == 35 and back.mag is not None and np.isnan(back.mag[:10]).all()
    np.testing.assert_allclose(back.mag[10:30], nine["mag"], rtol=1e-7)
    np.testing.assert_allclose(back.acc[:10], six["acc"], rtol=1e-7)
    if with_step:
        assert back.step is not None and list(back.step[:10]) == ["pose a"] * 10 and back.step[-1] == "pose b"
    assert [p.name for p in tmp_path.iterdir()] == ["late.csv"]  # no copy left beside it


def test_a_csv_that_cannot_be_widened_stays_whole_and_counts_the_fields_left_out(tmp_path: Path,
                                                                                 monkeypatch) -> None:
    import station.acquisition.capture_csv as capture_csv

    def full_disk(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(capture_csv.os, "replace", full_disk)
    w = CsvCaptureWriter(tmp_path / "late.csv")
    w.write(make_samples(10))
    w.write(make_mag_samples(20, first_seq=10))
    w.write(make_mag_samples(5, first_seq=30))
    w.close()
    assert w.rows == 35 and w.field_dropped == 25
    back = read_capture(tmp_path / "late.csv")
    assert len(back) == 35 and back.mag is None
    assert [p.name for p in tmp_path.iterdir()] == ["late.csv"]


def test_h5_mag_dataset_round_trip_and_late_field(tmp_path: Path) -> None:
    six, nine = make_samples(10), make_mag_samples(30, first_seq=10)
    w = H5CaptureWriter(tmp_path / "c.h5")
    w.write(six)  # before the field appears: filled with NaN when the dataset is made
    w.write(nine)
    w.close()
    back = read_capture(tmp_path / "c.h5")
    assert back.mag is not None and back.mag.shape == (40, 3)
    assert np.isnan(back.mag[:10]).all() and np.array_equal(back.mag[10:], nine["mag"].astype(float))
    raw = read_samples(tmp_path / "c.h5")
    assert has_mag(raw) and raw[10:].tobytes() == nine.tobytes()
    w6 = H5CaptureWriter(tmp_path / "six.h5")
    w6.write(six)
    w6.close()
    assert read_capture(tmp_path / "six.h5").mag is None and not has_mag(read_samples(tmp_path / "six.h5"))


# ---------------------------------------------------------------------------------- recorder over a pty


@pytest.mark.parametrize("suffix", [".csv", ".h5"])
def test_recorder_over_a_pty_keeps_the_field(tmp_path: Path, suffix: str) -> None:
    sent = make_mag_samples(1500)
    sent["mag"][100] = np.nan
    pty = RawPty()
    try:
        with open_device(pty.path) as dev:
            pty.write(encode_samples(sent))
            result = record(dev, tmp_path / f"cap{suffix}", duration_s=1.0, handle_sigint=False)
    finally:
        pty.close()
    back = read_capture(result.path)
    assert result.rows == len(back) >= 990
    assert back.mag is not None
    n = len(back)
    assert np.allclose(back.mag, sent["mag"][:n].astype(float), equal_nan=True, rtol=1e-7)


def test_capture_says_when_a_late_field_could_not_be_kept(tmp_path: Path, monkeypatch, capsys) -> None:
    import threading

    import station.acquisition.capture_csv as capture_csv
    from station import cli

    def full_disk(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(capture_csv.os, "replace", full_disk)
    six, nine = make_samples(4000), make_mag_samples(1500, first_seq=4000)
    pty = RawPty()
    stop = threading.Event()

    def feed() -> None:  # in real time: 4 s without a field (the capture starts in them), then with one
        for batch in (six, nine):
            for a in range(0, len(batch), 20):
                if stop.wait(0.02):
                    return
                pty.write(encode_samples(batch[a:a + 20]))

    feeder = threading.Thread(target=feed)
    feeder.start()
    try:
        code = cli.main(["capture", "--port", pty.path, "--duration", "4.5", "-o",
                         str(tmp_path / "late.csv")])
    finally:
        stop.set()
        feeder.join()
        pty.close()
    out = capsys.readouterr().out
    assert code == 0, out
    assert "the magnetic field came after the first rows" in out and "capture to .h5 to keep it" in out
    assert read_capture(tmp_path / "late.csv").mag is None


# ---------------------------------------------------------------------------------- the simulated unit


def _dip_deg(acc: np.ndarray, field_body: np.ndarray) -> np.ndarray:
    """Angle of the field below the horizontal plane the specific force (up) defines, degrees."""
    up = acc / np.linalg.norm(acc, axis=1)[:, None]
    return np.degrees(np.arcsin(-np.sum(up * field_body, axis=1) / np.linalg.norm(field_body, axis=1)))


def test_earth_field_in_world_axes() -> None:
    earth = EarthField(magnitude_ut=48.0, dip_deg=64.0, declination_deg=10.0)
    north_facing = earth.world(heading_deg=10.0)  # world x towards magnetic north
    assert np.allclose(north_facing, 48.0 * np.array([np.cos(np.radians(64)), 0.0, -np.sin(np.radians(64))]))
    east_facing = earth.world(heading_deg=100.0)  # world x points magnetic east, world y magnetic north
    assert abs(east_facing[0]) < 1e-9 and east_facing[1] > 0
    assert np.isclose(np.linalg.norm(earth.world(37.0)), 48.0)


def test_mag_truth_measure_and_correct_are_inverse() -> None:
    truth = MagTruth.random(4)
    assert np.allclose(truth.soft_iron, truth.soft_iron.T)
    angle = np.degrees(np.arccos((np.trace(truth.rotation) - 1) / 2))
    assert 1.0 <= angle <= 2.0
    b = np.random.default_rng(0).normal(0, 30, (100, 3))
    exact = MagTruth(hard_iron=truth.hard_iron, soft_iron=truth.soft_iron, rotation=truth.rotation)
    assert np.allclose(exact.correct(exact.measure(b)), b)


@pytest.mark.parametrize("kind", ["sphere", "desk"])
def test_mag_capture_sessions_carry_the_truths_field(kind: str) -> None:
    cap, truth = mag_capture(kind, seed=2, rate_hz=50.0, n_poses=12)
    assert cap.mag is not None and cap.mag.shape == (len(cap), 3)
    corrected = truth.mag.correct(cap.mag)
    magnitude = np.linalg.norm(corrected, axis=1)
    assert abs(magnitude.mean() - 50.0) < 0.05 and magnitude.std() < 0.4
    still = np.linalg.norm(cap.gyro - np.median(cap.gyro, axis=0), axis=1) < np.radians(1.0)
    dip = _dip_deg(cap.acc[still], corrected[still])
    assert abs(np.median(dip) - 60.0) < 1.0  # the accelerometer's own errors tilt it by a few tenths
    tilt = np.degrees(np.arccos(np.clip(cap.acc[:, 2] / np.linalg.norm(cap.acc, axis=1), -1, 1)))
    if kind == "desk":
        assert tilt.max() < 46.0
    else:
        assert tilt.max() > 120.0


def test_sim_url_options_make_a_nine_axis_unit() -> None:
    opts = parse_sim_url("sim://?mag=1&seed=3&field=45&dip=-30&declination=5&scenario=mag-desk")
    assert opts.mag is not None and opts.mag.field == EarthField(45.0, -30.0, 5.0)
    assert parse_sim_url("sim://?seed=3").mag is None and parse_sim_url("sim://?mag=0&field=40").mag is None
    with pytest.raises(ValueError, match="dip"):
        parse_sim_url("sim://?mag=1&dip=100")
    with pytest.raises(ValueError, match="field"):
        parse_sim_url("sim://?field=strong")
    assert parse_sim_url("sim://?mag=1&heading=90").heading == 90.0
    with pytest.raises(ValueError, match="heading"):
        parse_sim_url("sim://?heading=400")


def test_pty_end_to_end_capture_of_a_mag_unit_matches_what_was_sent(tmp_path: Path) -> None:
    truth = nine_axis_unit(5, EarthField(magnitude_ut=47.0, dip_deg=55.0))
    device = SimDevice(truth, seed=5, rate_hz=200, scenario="mag-sphere")
    paths = [tmp_path / "mag.h5", tmp_path / "mag.csv"]
    with PtyServer(device, record=True, speed=10) as server:
        for path in paths:
            with open_device(server.port_path) as dev:
                result = record(dev, path, duration_s=8.0, handle_sigint=False)
            assert result.ended_by == "duration" and result.error is None
        sent = server.sent()
    assert has_mag(sent)
    got = read_samples(paths[0])
    first = int(got["seq"][0])
    assert got.tobytes() == sent[first : first + len(got)].tobytes()  # bit-exact, field included
    for path in paths:
        cap = read_capture(path)
        assert cap.mag is not None and len(cap) >= 1500
        magnitude = np.linalg.norm(truth.mag.correct(cap.mag), axis=1)
        assert abs(magnitude.mean() - 47.0) < 0.1


# native: uT as float32; MotionCal lines: 0.1 uT counts; VectorNav: 1e-4 gauss (0.01 uT)
@pytest.mark.parametrize(("protocol", "tolerance_ut"), [("native", 0.1), ("motioncal", 0.2), ("vnymr", 0.1)])
def test_simulate_command_serves_a_mag_unit(tmp_path: Path, protocol: str, tolerance_ut: float) -> None:
    cli = [str(Path(sys.executable).with_name("imu-station"))]
    link = tmp_path / "imu"
    sim = subprocess.Popen(cli + ["simulate", "--mag", "field=40,dip=70", "--scenario", "mag-desk",
                                  "--protocol", protocol, "--seed", "7", "--speed", "10", "--link", str(link),
                                  "--duration", "60"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    # text lines carry no clock: the capture dates them at the simulated unit's 200 Hz
    reading = ["--protocol", "ascii:@200"] if protocol != "native" else []
    try:
        lines = [sim.stdout.readline() for _ in range(3)]
        assert any("magnetometer: local field 40 uT, dip 70 deg" in line for line in lines), lines
        out = tmp_path / "desk.csv"
        cap_proc = subprocess.run(cli + ["capture", "--port", str(link), *reading, "--duration", "3",
                                         "-o", str(out)], capture_output=True, text=True, timeout=60)
        assert cap_proc.returncode == 0, cap_proc.stderr
    finally:
        sim.terminate()
        sim.wait(timeout=10)
    cap = read_capture(out)
    truth = mag_from_options({"mag": "1", "field": "40", "dip": "70"}, 7)
    assert truth is not None and cap.mag is not None and len(cap) > 100
    assert abs(np.linalg.norm(truth.correct(cap.mag), axis=1).mean() - 40.0) < tolerance_ut
    assert _header(out).endswith("mx,my,mz")


def test_capture_field_scales_an_xsens_units_field(tmp_path: Path) -> None:
    cli = [str(Path(sys.executable).with_name("imu-station"))]
    link = tmp_path / "mti"
    sim = subprocess.Popen(cli + ["simulate", "--mag", "--protocol", "xsens", "--seed", "8", "--speed", "5",
                                  "--link", str(link), "--duration", "60"],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        for _ in range(3):
            sim.stdout.readline()
        out = tmp_path / "mti.h5"

        def capture(*options: str) -> subprocess.CompletedProcess:
            return subprocess.run(cli + ["capture", "--port", str(link), *options], capture_output=True,
                                  text=True, timeout=60)

        done = capture("--protocol", "xsens", "--field", "50", "--duration", "2", "-o", str(out))
        assert done.returncode == 0, done.stderr
        plain = capture("--protocol", "xsens", "--duration", "1", "-o", str(tmp_path / "plain.csv"))
        assert plain.returncode == 0 and "recorded only with --field UT" in plain.stderr
        refused = capture("--field", "50", "--duration", "1", "-o", str(tmp_path / "n.csv"))
        assert refused.returncode == 4 and "--field scales the normalised magnetic field" in refused.stderr
    finally:
        sim.terminate()
        sim.wait(timeout=10)
    cap = read_capture(out)
    truth = mag_from_options({"mag": "1"}, 8)
    assert truth is not None and cap.mag is not None and len(cap) > 100
    assert abs(np.linalg.norm(truth.correct(cap.mag), axis=1).mean() - 50.0) < 0.1
    assert read_capture(tmp_path / "plain.csv").mag is None


def test_sequence_runner_carries_the_field_to_its_capture_and_file(tmp_path: Path) -> None:
    from station.acquisition.operator import ScriptedOperator, SimulatedOperator
    from station.acquisition.recorder import Recorder
    from station.acquisition.runner import RecorderSink, SequenceRunner
    from station.acquisition.sequences import PoseStep, Sequence

    truth = nine_axis_unit(9)
    server = PtyServer(SimDevice(truth, seed=9, rate_hz=200.0, scenario="still"), speed=4.0).start()
    try:
        with open_device(server.port_path) as device:
            device.get_info()
            path = tmp_path / "run.h5"
            recorder = Recorder(path, device=device.info, with_step=True, port=device.port, protocol="native")
            seq = Sequence("two", (PoseStep("+z", 0.6), PoseStep("-x", 0.6)))
            operator = SimulatedOperator(server.device, ScriptedOperator(), move_s=0.4)
            result = SequenceRunner(device, seq, operator, sink=RecorderSink(recorder, device)).run()
            recorder.close()
    finally:
        server.stop()
    assert result.outcome == "completed"
    for cap in (result.capture, read_capture(path)):
        assert cap.mag is not None and len(cap.mag) == len(cap)
        up = {label: truth.mag.correct(cap.mag[rows]).mean(axis=0) for label, rows in cap.segments()}
        # lying flat the field's vertical part is on -z; on its side (-x up) on +x
        assert up["+z"][2] < -30 and up["-x"][0] > 30
