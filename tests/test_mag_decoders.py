"""The magnetic field in the other decoders' sample batches: Xsens MagneticField (four precisions,
normalised, scaled by the local field), MAVLink SCALED_IMU / HIGHRES_IMU / RAW_IMU, text-line columns
with units, frame descriptions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fuzz_cases import nine_axis
from test_proto_xsens import make_samples, read_golden, xyz

from protocols import ascii_lines, mavlink, xsens
from protocols.ascii_lines import AsciiDecoder, parse_columns
from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE, has_mag
from protocols.frame import FrameDecoder, encode_frames
from protocols.frame_description import describe
from protocols.mag_batches import join_batches
from protocols.registry import make_decoder
from protocols.xsens import MID_MTDATA2, XsensDecoder, parse_mtdata2

# Largest error of one value of each precision, in a.u. (12.20 and 16.32 round to their last bit).
PRECISION_STEP = {"float32": 6e-8, "fp1220": 2.0**-21, "fp1632": 2.0**-33, "float64": 1e-15}


def _decode(decoder, data: bytes, chunk: int = 97) -> np.ndarray:
    out = [decoder.feed(data[i : i + chunk]).samples for i in range(0, len(data), chunk)]
    return join_batches([*out, decoder.flush().samples])


# ---------------------------------------------------------------------------------- Xsens


@pytest.mark.parametrize("precision", list(PRECISION_STEP))
def test_xsens_magnetic_field_in_every_precision(precision: str) -> None:
    sent = nine_axis(make_samples(60, seed=3))
    data = xsens.encode_samples(sent, precision=precision, field_ut=48.0)
    got = _decode(XsensDecoder(field_ut=48.0), data)
    assert got.dtype == MAG_SAMPLE_DTYPE and len(got) == 60
    # the normalised value's rounding, scaled to uT, then float32 (relative 6e-8)
    tolerance = PRECISION_STEP[precision] * 48.0 + 1e-7 * np.abs(sent["mag"]).max()
    np.testing.assert_allclose(got["mag"], sent["mag"], rtol=0, atol=tolerance)
    assert got["acc"].tobytes() == sent["acc"].tobytes() or precision != "float32"


def test_xsens_field_is_normalised_on_the_wire_and_left_out_without_field() -> None:
    sent = nine_axis(make_samples(5))
    data = xsens.encode_samples(sent, field_ut=50.0)
    payload = data[4 : 4 + data[3]]  # the first (short-form) frame's payload
    packet = parse_mtdata2(payload)
    assert packet.mag is not None and np.allclose(packet.mag, sent["mag"][0] / 50.0, rtol=1e-6)
    plain = XsensDecoder()
    got = _decode(plain, data)
    assert got.dtype == SAMPLE_DTYPE and len(got) == 5 and plain.mag_unscaled == 5


def test_xsens_samples_without_a_field_are_nan_once_a_field_came() -> None:
    sent = nine_axis(make_samples(6))
    sent["mag"][[0, 4]] = np.nan  # packets 0 and 4 carry no MagneticField item
    got = _decode(XsensDecoder(field_ut=50.0), xsens.encode_samples(sent, field_ut=50.0), chunk=1000)
    assert got.dtype == MAG_SAMPLE_DTYPE
    assert np.isnan(got["mag"][[0, 4]]).all() and np.isfinite(got["mag"][[1, 2, 3, 5]]).all()


def test_xsens_option_sets_field_and_source() -> None:
    dec = make_decoder("xsens:field=49.5")
    assert isinstance(dec, XsensDecoder) and dec.field_ut == 49.5 and dec.source is None
    both = make_decoder("xsens:hr,field=30")
    assert isinstance(both, XsensDecoder) and both.source == "hr" and both.field_ut == 30.0
    with pytest.raises(ValueError, match="field"):
        make_decoder("xsens:field=strong")
    with pytest.raises(ValueError, match="0..1000"):
        XsensDecoder(field_ut=-3)


def test_xsens_golden_folder_5_magnetic_field(reference_data: Path) -> None:
    """A real MTi's MagneticField items (folder 5: orientation and field, no inertial data)."""
    base = reference_data / "xsens-mtdata2" / "5"
    blocks = read_golden(base / "output.golden")
    dec = XsensDecoder(field_ut=50.0)
    out = dec.feed((base / "output.bin").read_bytes())
    expected = [xyz(b["MagneticField"]) for b in blocks if "MagneticField" in b]
    fields = [parse_mtdata2(m.payload).mag for m in out.messages if m.msg_id == MID_MTDATA2]
    got = [f for f in fields if f is not None]
    assert len(got) == len(expected) >= 80
    np.testing.assert_allclose(np.array(got, dtype=np.float32), np.array(expected, dtype=np.float32), rtol=0,
                               atol=0)
    # normalised: a unit calibrated where it sits reads about 1 a.u. (this one about a quarter)
    assert 0.1 < np.median(np.linalg.norm(got, axis=1)) < 2.0
    assert dec.items_seen["MagneticField(float32)"] == len(expected)
    assert len(out.samples) == 0  # a packet becomes a sample only with inertial data


# ---------------------------------------------------------------------------------- MAVLink

pytestmark_mavlink = pytest.mark.skipif(not mavlink.pymavlink_available(), reason="needs pymavlink")


@pytestmark_mavlink
@pytest.mark.parametrize(("message", "step_ut"), [("HIGHRES_IMU", 1e-5), ("SCALED_IMU", 0.05),
                                                  ("SCALED_IMU2", 0.05), ("RAW_IMU", 0.05)])
def test_mavlink_magnetometer_fields(message: str, step_ut: float) -> None:
    sent = nine_axis(make_samples(30, seed=4))
    got = _decode(mavlink.MavlinkDecoder(), mavlink.encode_samples(sent, message))
    assert got.dtype == MAG_SAMPLE_DTYPE and len(got) == 30
    np.testing.assert_allclose(got["mag"], sent["mag"], rtol=1e-6, atol=step_ut)


@pytestmark_mavlink
def test_mavlink_units_of_a_hand_built_message() -> None:
    dialect = mavlink.load_dialect()
    mav = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    scaled = mav.scaled_imu_encode(1000, 0, 0, 1000, 0, 0, 0, 215, -40, 432, 2500).pack(mav)
    highres = mav.highres_imu_encode(5, 0, 0, 9.8, 0, 0, 0, 0.215, -0.04, 0.432, 1013.0, 0, 0, 25.0,
                                     0x1FFF).pack(mav)
    a = _decode(mavlink.MavlinkDecoder(), scaled)
    b = _decode(mavlink.MavlinkDecoder(), highres)
    np.testing.assert_allclose(a["mag"][0], [21.5, -4.0, 43.2], rtol=1e-6)  # mgauss -> uT
    np.testing.assert_allclose(b["mag"][0], [21.5, -4.0, 43.2], rtol=1e-6)  # gauss -> uT


@pytestmark_mavlink
def test_mavlink_without_magnetometer_stays_six_axis() -> None:
    dialect = mavlink.load_dialect()
    mav = dialect.MAVLink(None, srcSystem=1, srcComponent=1)
    zero_field = mav.scaled_imu_encode(1000, 0, 0, 1000, 0, 0, 0, 0, 0, 0, 2500).pack(mav)
    unflagged = mav.highres_imu_encode(5, 0, 0, 9.8, 0, 0, 0, 0.2, 0, -0.4, 1013.0, 0, 0, 25.0,
                                       0x1E3F).pack(mav)  # bits 6-8 (the field) not updated
    assert _decode(mavlink.MavlinkDecoder(), zero_field).dtype == SAMPLE_DTYPE
    assert _decode(mavlink.MavlinkDecoder(), unflagged).dtype == SAMPLE_DTYPE
    assert _decode(mavlink.MavlinkDecoder(), mavlink.encode_samples(make_samples(3), "SCALED_IMU")).dtype \
        == SAMPLE_DTYPE


# ---------------------------------------------------------------------------------- text lines


@pytest.mark.parametrize(("unit", "factor"), [("uT", 1.0), ("mG", 0.1), ("G", 100.0), ("nT", 1e-3)])
def test_text_columns_with_field_units(unit: str, factor: float) -> None:
    spec = f"t,ax,ay,az,gx,gy,gz,mx:{unit},my:{unit},mz:{unit}"
    field = ",".join(f"{v / factor:.9g}" for v in (20.0, -5.0, 42.0))
    lines = b"".join(f"{0.01 * i:.2f},0,0,9.81,0,0,0.1,{field}\n".encode() for i in range(20))
    for chunk in (7, len(lines)):  # the line-by-line path and the fast block path
        got = _decode(AsciiDecoder(spec), lines, chunk=chunk)
        assert got.dtype == MAG_SAMPLE_DTYPE and len(got) == 20
        np.testing.assert_allclose(got["mag"], np.tile([20.0, -5.0, 42.0], (20, 1)), rtol=1e-6)


def test_text_columns_round_trip_and_rules() -> None:
    sent = nine_axis(make_samples(25))
    spec = ascii_lines.DEFAULT_COLUMNS + ",mx:G,my:G,mz:G"
    got = _decode(AsciiDecoder(spec), ascii_lines.encode_csv(sent, spec), chunk=50)
    np.testing.assert_allclose(got["mag"], sent["mag"], rtol=1e-6)
    assert parse_columns("ax,ay,az,gx,gy,gz,mx,my,mz").has_mag
    assert not parse_columns("ax,ay,az,gx,gy,gz").has_mag
    with pytest.raises(ValueError, match="all three"):
        parse_columns("ax,ay,az,gx,gy,gz,mx,my")
    with pytest.raises(ValueError, match="unit"):
        parse_columns("ax,ay,az,gx,gy,gz,mx:tesla,my,mz")


def test_text_field_nan_and_implausible_values() -> None:
    spec = "ax,ay,az,gx,gy,gz,mx,my,mz"
    lines = b"0,0,9.8,0,0,0,20,1,40\n0,0,9.8,0,0,0,nan,nan,nan\n0,0,9.8,0,0,0,20,1,1e9\n0,0,9.8,0,0,0,1,2,3\n"
    dec = AsciiDecoder(spec)
    got = _decode(dec, b"\n" + lines, chunk=5)
    assert len(got) == 3 and np.isnan(got["mag"][1]).all() and dec.stats.bad_payloads == 1


# ---------------------------------------------------------------------------------- frame descriptions


def _bench_desc():
    from frame_helpers import BENCH_32

    return describe(BENCH_32)


def test_frame_description_with_all_three_fields_records_them() -> None:
    from frame_helpers import still_samples, values_from_samples

    desc = _bench_desc()
    values = values_from_samples(desc, still_samples(50, 200.0))
    got = _decode(FrameDecoder(desc), encode_frames(desc, values), chunk=33)
    assert got.dtype == MAG_SAMPLE_DTYPE and len(got) == 50
    np.testing.assert_allclose(got["mag"], np.tile([20.0, 40.0, 60.0], (50, 1)), atol=0.075)  # scale 0.15


def test_frame_description_with_only_some_fields_carries_none() -> None:
    from frame_helpers import SPEC_EXAMPLE, still_samples, values_from_samples

    desc = describe(SPEC_EXAMPLE)  # the spec's example: mx alone
    values = values_from_samples(desc, still_samples(10, 200.0))
    dec = FrameDecoder(desc)
    got = _decode(dec, encode_frames(desc, values), chunk=1000)
    assert not has_mag(got) and len(got) == 10
