"""Protocol auto-detection from the first bytes, and the ``auto`` decoder that loses none of them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocols import ascii_lines, mavlink, native, xsens
from protocols.base import SAMPLE_DTYPE
from protocols.detect import AutoDecoder, detect
from protocols.mag_batches import join_batches
from protocols.registry import DECODERS, make_decoder


def make_samples(n: int, seed: int = 0, rate_hz: float = 100.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = np.round(np.arange(n) * 1e6 / rate_hz)
    s["acc"] = rng.normal(0, 5, (n, 3))
    s["gyro"] = rng.normal(0, 1, (n, 3))
    s["temp"] = 25 + rng.normal(0, 0.1, n)
    return s


def streams() -> dict[str, bytes]:
    s = make_samples(40)
    out = {
        "native": native.encode_device_info({"serial": "S1", "model": "m", "firmware": "1", "rate_hz": 100})
        + native.encode_samples(s),
        "xsens": xsens.encode_samples(s),
        "ascii": ascii_lines.encode_samples(s, "vnymr"),
    }
    if mavlink.pymavlink_available():
        out["mavlink"] = mavlink.encode_samples(s, "SCALED_IMU", heartbeat_every=10)
    return out


@pytest.mark.parametrize("protocol", ["native", "xsens", "ascii", "mavlink"])
def test_each_protocol_is_recognised_from_any_point_of_its_stream(protocol: str) -> None:
    data = streams().get(protocol)
    if data is None:
        pytest.skip("pymavlink is not installed")
    for cut in (0, 7, 301):
        found = detect(data[cut : cut + 1500])
        assert found.protocol == protocol, found.explanation
        assert found.samples >= 3 and found.rate_hz == pytest.approx(100, rel=0.01)
        assert "100 Hz" in found.explanation


def test_explanations_say_what_was_found() -> None:
    s = streams()
    assert detect(s["native"][:1000]).explanation.startswith("native protocol: ")
    text = detect(s["xsens"][:1000]).explanation
    assert "MTData2 packets" in text and "Acceleration(float32)" in text and "RateOfTurn(float32)" in text
    assert "VectorNav" not in detect(s["ascii"]).explanation and "vectornav" in detect(s["ascii"]).explanation


def test_real_xsens_capture_is_recognised(reference_data: Path) -> None:
    data = (reference_data / "xsens-mtdata2" / "1" / "output.bin").read_bytes()
    found = detect(data[1000:3000])
    assert found.protocol == "xsens" and "Acceleration(float32)" in found.explanation


def test_xsens_without_inertial_data_is_recognised_and_the_user_told_what_to_add(
        reference_data: Path) -> None:
    data = (reference_data / "xsens-mtdata2" / "5" / "output.bin").read_bytes()
    found = detect(data[:2000])
    assert found.protocol == "xsens" and found.samples == 0
    assert "none carries Acceleration" in found.explanation and "Temperature(float32)" in found.explanation


def test_mavlink_without_imu_messages_says_how_to_ask_for_them() -> None:
    pytest.importorskip("pymavlink")
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    mav = dialect.MAVLink(None, 1, 1)
    data = b"".join(mav.heartbeat_encode(2, 3, 0, 0, 0).pack(mav) for _ in range(5))
    found = detect(data)
    assert found.protocol == "mavlink" and found.samples == 0 and "RAW_IMU" in found.explanation


def test_unrecognised_bytes_are_described() -> None:
    short = detect(b"hello")
    assert short.protocol is None and short.need_more
    rng = np.random.default_rng(0)
    noise = detect(rng.integers(0, 256, 5000, dtype=np.uint8).tobytes())
    assert noise.protocol is None and not noise.need_more and "binary, starting" in noise.explanation
    text = detect(b"Booting...\r\nNo sensor found!\r\n" * 200)
    assert text.protocol is None and "text, starting 'Booting...'" in text.explanation


def test_csv_lines_with_a_header_are_recognised() -> None:
    data = b"t,ax,ay,az,gx,gy,gz,temp\n" + ascii_lines.encode_csv(make_samples(10))
    found = detect(data)
    assert found.protocol == "ascii" and found.samples == 10 and "csv" in found.explanation


@pytest.mark.parametrize("protocol", ["native", "xsens", "ascii", "mavlink"])
def test_auto_decoder_loses_no_sample(protocol: str) -> None:
    data = streams().get(protocol)
    if data is None:
        pytest.skip("pymavlink is not installed")
    dec = make_decoder("auto")
    rng = np.random.default_rng(1)
    out, pos = [], 0
    while pos < len(data):
        n = int(rng.integers(1, 60))
        out.append(dec.feed(data[pos : pos + n]).samples)
        pos += n
    out.append(dec.flush().samples)
    samples = join_batches(out)  # VectorNav lines carry a field: nine-axis once the first is read
    assert isinstance(dec, AutoDecoder) and dec.protocol == protocol
    assert samples["seq"].tolist() == list(range(40))
    assert dec.stats.samples == 40 and dec.stats.errors == 0


def test_auto_decoder_holds_a_bounded_buffer_of_noise() -> None:
    dec = AutoDecoder()
    rng = np.random.default_rng(2)
    for _ in range(20):
        dec.feed(rng.integers(0, 256, 1000, dtype=np.uint8).tobytes())
        assert len(dec._buf) == 0  # the candidate decoders read the bytes as they come
    assert dec.protocol is None and dec.stats.garbage_bytes == 20_000
    out = dec.feed(native.encode_samples(make_samples(30)))  # tried again: a quarter more arrived
    assert dec.protocol == "native" and out.samples["seq"].tolist() == list(range(30))


def test_registry_knows_every_protocol() -> None:
    assert {"native", "xsens", "mavlink", "ascii", "auto"} <= set(DECODERS)
    assert make_decoder("xsens").name == "xsens"
    with pytest.raises(ValueError, match="unknown protocol"):
        make_decoder("nmea")
    ascii_dec = make_decoder("ascii:t:ms,ax:g,ay:g,az:g,gx:dps,gy:dps,gz:dps")
    out = ascii_dec.feed(b"10,0,0,1,0,0,90\n").samples
    assert out["t_us"][0] == 10_000 and out["acc"][0][2] == pytest.approx(9.80665)
    assert out["gyro"][0][2] == pytest.approx(np.pi / 2)
    with pytest.raises(ValueError, match="takes no option"):
        make_decoder("native:fast")
    with pytest.raises(ValueError, match="unknown Xsens sample source"):
        make_decoder("xsens:fast")
    with pytest.raises(ValueError, match="unknown unit"):
        make_decoder("ascii:t:fortnights,ax,ay,az,gx,gy,gz")
