"""``imu-station capture --protocol auto|xsens|ascii --columns``: real ptys, files read back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from device_helpers import BytePty

from mocks.device import SimDevice
from mocks.encoders_extra import EXTRA_ENCODERS  # noqa: F401  (registers the encoders)
from mocks.pty_server import PtyServer
from protocols.ascii_lines import STANDARD_GRAVITY, encode_csv
from protocols.base import SAMPLE_DTYPE
from station.acquisition.capture import read_capture
from station.cli import main


def test_auto_recognises_an_xsens_unit_says_so_and_records_it(tmp_path: Path, capsys) -> None:
    out = tmp_path / "mti.csv"
    with PtyServer(SimDevice(seed=2, rate_hz=100, encoder="xsens"), record=True) as server:
        code = main(["capture", "--port", server.port_path, "--protocol", "auto", "--duration", "1",
                     "-o", str(out)])
        sent = server.sent()
    err = capsys.readouterr().err
    assert code == 0, err
    assert "protocol: xsens: Xsens Xbus:" in err and "Acceleration(float32)" in err
    cap = read_capture(out)
    assert 95 <= len(cap) <= 105
    index = np.searchsorted(sent["t_us"], np.round(cap.t * 1e6).astype(np.int64))
    np.testing.assert_allclose(cap.acc, sent["acc"][index], rtol=1e-6)
    np.testing.assert_allclose(cap.gyro, sent["gyro"][index], rtol=1e-6)


def test_text_lines_without_a_clock_are_timed_at_the_given_rate(tmp_path: Path, capsys) -> None:
    out = tmp_path / "motioncal.csv"
    with PtyServer(SimDevice(seed=3, rate_hz=50, encoder="motioncal")) as server:
        code = main(["capture", "--port", server.port_path, "--protocol", "auto", "--rate", "50",
                     "--duration", "1", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "protocol: ascii: text lines:" in err and "motioncal" in err and "carry no clock" in err
    cap = read_capture(out)
    assert 45 <= len(cap) <= 55 and np.allclose(np.diff(cap.t), 0.02)
    assert np.allclose(np.linalg.norm(cap.acc, axis=1), 9.8, atol=0.3)


def test_ascii_columns_in_device_units_become_si(tmp_path: Path, capsys) -> None:
    n = 300
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["t_us"] = 1_000_000 + np.arange(n) * 10_000
    s["acc"] = [0.0, 0.0, STANDARD_GRAVITY]
    s["gyro"] = [np.pi / 2, 0.0, 0.0]
    spec = "t:ms,ax:g,ay:g,az:g,gx:dps,gy:dps,gz:dps"
    out = tmp_path / "arduino.csv"
    with BytePty.lines(encode_csv(s, spec)) as pty:
        code = main(["capture", "--port", pty.path, "--protocol", "ascii", "--columns", spec,
                     "--duration", "0.5", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    cap = read_capture(out)
    assert len(cap) >= 40
    np.testing.assert_allclose(cap.acc, np.tile([0, 0, STANDARD_GRAVITY], (len(cap), 1)), atol=1e-6)
    np.testing.assert_allclose(cap.gyro[:, 0], np.pi / 2, rtol=1e-6)
    assert np.allclose(np.diff(cap.t), 0.01)


def test_auto_on_noise_explains_what_it_saw(tmp_path: Path, capsys) -> None:
    noise = np.random.default_rng(0).integers(0, 256, 60_000, dtype=np.uint8).tobytes()
    with BytePty.lines(noise, lines_per_write=50, period_s=0.005) as pty:
        code = main(["capture", "--port", pty.path, "--protocol", "auto", "--duration", "1",
                     "-o", str(tmp_path / "x.csv")])
    err = capsys.readouterr().err
    assert code == 3 and "no known protocol" in err and "binary, starting" in err
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.parametrize("argv, words", [
    (["--protocol", "xsens", "--columns", "t,ax,ay,az,gx,gy,gz"], "--columns applies to --protocol ascii"),
    (["--protocol", "ascii", "--columns", "t,ax,ay,az,gx,gy"], "lacks gz"),
])
def test_bad_column_options_are_usage_errors(tmp_path: Path, capsys, argv: list[str], words: str) -> None:
    code = main(["capture", "--port", "/dev/null-imu", *argv, "-o", str(tmp_path / "x.csv")])
    assert code == 4 and words in capsys.readouterr().err


def test_protocol_options_on_the_command_line(tmp_path: Path, capsys) -> None:
    out = tmp_path / "imu2.csv"
    with PtyServer(SimDevice(seed=5, rate_hz=50, encoder="mavlink-scaled"), record=True) as server:
        code = main(["capture", "--port", server.port_path, "--protocol", "mavlink:SCALED_IMU", "--duration",
                     "0.5", "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    assert len(read_capture(out)) >= 20
    for bad, words in [("nmea", "unknown protocol 'nmea'"), ("xsens:fast", "unknown Xsens sample source"),
                       ("native:x", "takes no option")]:
        with pytest.raises(SystemExit):
            main(["capture", "--port", "/dev/null-imu", "--protocol", bad, "-o", str(out)])
        assert words in capsys.readouterr().err
