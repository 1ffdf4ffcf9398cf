"""``imu-station frame check`` (a raw capture, a real pty) and ``imu-station frame guess``: the values and
rates shown, the wrong scales and byte orders flagged, and descriptions proposed from raw bytes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from device_helpers import BytePty
from frame_helpers import DATA, SPEC_EXAMPLE, damaged_stream, plain_frames, still_samples

from protocols.frame_description import describe
from station.cli import main
from station.frames.reader import load_decoder, load_description, shipped_descriptions


def _variant(tmp_path: Path, name: str, **changes: object) -> Path:
    """A copy of a shipped description with top-level keys or every accelerometer field changed."""
    doc = yaml.safe_load(shipped_descriptions()[name].read_text(encoding="utf-8"))
    acc_scale = changes.pop("acc_scale", None)
    doc.update(changes)
    if acc_scale is not None:
        for f in doc["fields"]:
            if f["name"] in ("ax", "ay", "az"):
                f["scale"] = f["scale"] * acc_scale
    path = tmp_path / f"{name}-variant.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


@pytest.mark.parametrize("name", ["witmotion", "mpu6050_dump"])
def test_check_on_a_recording_shows_values_and_rates_and_flags_nothing(name: str, capsys) -> None:
    code = main(["frame", "check", name, "--file", str(DATA / f"{name}.bin")])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "598 frames" in out and "nothing looks wrong" in out and "the unit lies still" in out
    assert "1 damaged" in out if name == "witmotion" else "2 damaged" in out
    rate = load_description(name).rate_hz
    assert f"{rate:.1f}/s" in out or f"{rate - 0.7:.1f}/s" in out


def test_check_flags_a_wrong_accelerometer_scale_and_names_the_factor(tmp_path: Path, capsys) -> None:
    path = _variant(tmp_path, "mpu6050_dump", acc_scale=2.0)  # a +-4 g scale on a +-2 g chip
    code = main(["frame", "check", str(path), "--file", str(DATA / "mpu6050_dump.bin")])
    out = " ".join(capsys.readouterr().out.split())
    assert code == 1
    assert "|a| is 19.61 m/s^2 while the unit lies still, 2 g: multiply the accelerometer scales by 0.5" \
        in out


def test_check_flags_values_in_the_wrong_byte_order(tmp_path: Path, capsys) -> None:
    path = _variant(tmp_path, "mpu6050_dump", byte_order="little")
    code = main(["frame", "check", str(path), "--file", str(DATA / "mpu6050_dump.bin")])
    out = " ".join(capsys.readouterr().out.split())
    assert code == 1 and "jumps at random between samples" in out and "the byte order" in out


def test_check_flags_a_description_that_decodes_nothing(tmp_path: Path, capsys) -> None:
    path = _variant(tmp_path, "mpu6050_dump", sync=[0xA1, 0xB3])
    code = main(["frame", "check", str(path), "--file", str(DATA / "mpu6050_dump.bin")])
    out = " ".join(capsys.readouterr().out.split())
    assert code == 1 and "0 frames" in out and "no frame decoded" in out


def test_check_a_unit_live_through_a_pty(tmp_path: Path, capsys) -> None:
    desc_path = tmp_path / "acme.yaml"
    desc_path.write_text(yaml.safe_dump(SPEC_EXAMPLE), encoding="utf-8")
    desc = describe(SPEC_EXAMPLE)
    stream, _ = damaged_stream(plain_frames(desc, still_samples(1000, 200.0, seed=9)), desc.length, seed=9)
    with BytePty.chunked(stream, chunk=10 * desc.length, period_s=0.05, delay_s=0.3) as pty:
        code = main(["frame", "check", str(desc_path), "--port", pty.path, "--duration", "1.5"])
    out = capsys.readouterr().out
    assert code == 0, out
    frames = int(out.rsplit(" frames, ", 1)[0].rsplit("\n", 1)[-1])
    assert 150 <= frames <= 260 and "nothing looks wrong" in out and "acme-imu-v2" in out


def test_guess_proposes_the_description_a_stream_was_made_with(tmp_path: Path, capsys) -> None:
    desc = describe(SPEC_EXAMPLE)
    stream, good = damaged_stream(plain_frames(desc, still_samples(800, 200.0, seed=4)), desc.length, seed=4)
    raw = tmp_path / "raw.bin"
    raw.write_bytes(stream)
    assert main(["frame", "guess", str(raw)]) == 0
    proposed = capsys.readouterr().out
    doc = yaml.safe_load(proposed)
    assert doc["sync"] == [0xAA, 0x55] and doc["length"] == 28 and doc["byte_order"] == "little"
    assert doc["checksum"] == {"type": "crc16-ccitt-false", "from": 2, "to": 26, "at": 26}
    fields = {f["name"]: f for f in doc["fields"]}
    assert (fields["seq"]["at"], fields["seq"]["type"]) == (2, "u16")
    assert (fields["t"]["at"], fields["t"]["type"], fields["t"]["scale"]) == (4, "u32", 1e-6)
    assert [fields[n]["at"] for n in ("ax", "ay", "az", "gx", "gy", "gz", "temp")] == list(range(8, 22, 2))
    path = tmp_path / "guessed.yaml"
    path.write_text(proposed, encoding="utf-8")
    decoder = load_decoder(path)
    got = np.concatenate([decoder.feed(stream).samples, decoder.flush().samples])
    assert len(got) == good and decoder.stats.crc_errors == 1


def test_guess_finds_the_shipped_examples_framing(capsys) -> None:
    assert main(["frame", "guess", str(DATA / "mpu6050_dump.bin")]) == 0
    doc = yaml.safe_load(capsys.readouterr().out)
    assert doc["sync"] == [0xA1, 0xB2] and doc["length"] == 18 and doc["byte_order"] == "big"
    assert doc["checksum"] == {"type": "crc8", "from": 2, "to": 17, "at": 17}
    assert {"name": "seq", "at": 2, "type": "u8"} in doc["fields"]


def test_guess_on_noise_has_nothing_to_propose(tmp_path: Path, capsys) -> None:
    raw = tmp_path / "noise.bin"
    raw.write_bytes(np.random.default_rng(1).integers(0, 256, 20_000, dtype=np.uint8).tobytes())
    assert main(["frame", "guess", str(raw)]) == 4
    err = capsys.readouterr().err
    assert "nothing to propose" in err and str(raw) in err


def test_check_reads_a_port_at_the_speed_capture_does(tmp_path: Path) -> None:
    """Before: frame check read at 115200 by default while capture reads at 921600 (issue 31)."""
    from station.cli import build_parser

    check = build_parser("frame").parse_args(["frame", "check", "witmotion", "--port", "/dev/null"])
    capture = build_parser("capture").parse_args(["capture", "--port", "/dev/null", "-o",
                                                  str(tmp_path / "c.csv")])
    assert check.baud == capture.baud == 921_600
