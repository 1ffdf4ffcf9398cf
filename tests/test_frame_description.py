"""Frame description files (``station/frames/reader.py``): the manual's example is read as written; a file
that breaks a rule is refused naming the file, line, key and field, before any port opens (exit 4);
hostile YAML is refused quickly; the shipped examples decode their recordings."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest
from frame_helpers import DATA, example_stream

from protocols.units import STANDARD_GRAVITY
from station.cli import main
from station.errors import InputFileError
from station.frames.reader import load_decoder, load_description, shipped_descriptions

ROOT = Path(__file__).resolve().parent.parent
MANUAL = ROOT / "docs" / "reference" / "frame-description.md"


def _manual_example() -> str:
    return re.search(r"```yaml\n(.*?)```", MANUAL.read_text(encoding="utf-8"), re.S).group(1)  # type: ignore


def test_the_manuals_example_is_read_as_written(tmp_path: Path) -> None:
    path = tmp_path / "acme.yaml"
    path.write_text(_manual_example(), encoding="utf-8")
    desc = load_description(path)
    assert desc.name == "acme-imu-v2" and desc.length == 28 and desc.sync == b"\xaa\x55"
    cs = desc.checksum
    assert cs is not None and (cs.start, cs.end, cs.at) == (2, 26, 26)
    mx = desc.field("mx")
    assert mx is not None and mx.byte_order == "big" and desc.field("temp").offset == 25.0  # type: ignore


def _line_of(text: str, needle: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if needle in line)


# (what to replace in the manual's example, with what, the line's marker, the words the message holds)
BROKEN = [
    ("type: i16, scale: 0.0023956}", "type: i17, scale: 0.0023956}", "name: ax",
     ["fields[2].type", "field ax", "'i17'"]),
    ("{name: gz,   at: 18,", "{name: gz,   at: 27,", "name: gz",
     ["fields[7].at", "field gz", "past the frame's end"]),
    ("{name: gz,   at: 18,", "{name: gz,   at: 0,", "name: gz",
     ["fields[7].at", "field gz", "overlaps the sync"]),
    ("{name: temp, at: 20,", "{name: temp, at: 25,", "name: temp", ["fields[8].at", "field temp",
                                                                    "overlaps the checksum"]),
    ("  - {name: gy,   at: 16, type: i16, scale: 0.00026632}\n", "", "name: seq",
     ["fields", "missing required", "gy"]),
    ("rate_hz: 200 ", "rate_hz: 200\ncolour: red ", "colour", ["key 'colour'", "unknown key"]),
    ("{name: seq,  at: 2,  type: u16}", "{name: seq,  at: 2,  type: u16, sacle: 2}", "name: seq",
     ["fields[0].sacle", "field seq", "unknown key"]),
    ("type: crc16-ccitt-false", "type: crc16-ccitt-true", "type: crc16-ccitt-true", ["checksum.type"]),
    ("sync: [0xAA, 0x55]", "sync: [0xAA, 0x155]", "sync:", ["sync[1]", "0..255"]),
    ("byte_order: little", "byte_order: middle", "byte_order:", ["key 'byte_order'", "little or big"]),
    ("schema: imu-station/frame/1", "schema: imu-station/frame/2", "schema:", ["key 'schema'"]),
]


@pytest.mark.parametrize(("old", "new", "marker", "words"), BROKEN, ids=[b[3][0] for b in BROKEN])
def test_a_broken_rule_is_refused_naming_file_line_key_and_field(tmp_path: Path, capsys, old: str, new: str,
                                                                 marker: str, words: list[str]) -> None:
    text = _manual_example()
    assert old in text
    text = text.replace(old, new, 1)
    path = tmp_path / "board.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputFileError) as info:
        load_description(path)
    message = str(info.value)
    assert message.startswith(f"{path}, line {_line_of(text, marker)}: "), message
    for word in words:
        assert word in message
    # Every command that takes --protocol refuses it before opening the port (which does not exist:
    # opening it would be exit 3).
    with pytest.raises(SystemExit) as stop:
        main(["capture", "--port", "/dev/null-no-such-port", "--protocol", f"frame:{path}", "--duration", "1",
              "-o", str(tmp_path / "x.csv")])
    err = capsys.readouterr().err
    assert stop.value.code == 4 and message in err
    assert "Traceback" not in err and "null-no-such-port" not in err


def test_a_missing_file_names_the_shipped_descriptions(tmp_path: Path) -> None:
    with pytest.raises(InputFileError, match="does not exist.*mpu6050_dump, witmotion"):
        load_description(tmp_path / "nope.yaml")


def test_hostile_yaml_is_refused_quickly(tmp_path: Path) -> None:
    lines = ["schema: imu-station/frame/1", 'l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for level in range(1, 10):
        lines.append(f"l{level}: &l{level} [" + ", ".join([f"*l{level - 1}"] * 9) + "]")
    path = tmp_path / "laughs.yaml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    start = time.perf_counter()
    with pytest.raises(InputFileError, match="expands to more than"):
        load_description(path)
    assert time.perf_counter() - start < 1.0
    path.write_bytes(b"schema: x\n" + b"#" * 70_000)
    with pytest.raises(InputFileError, match="larger than 64 KiB"):
        load_description(path)


@pytest.mark.parametrize("name", ["witmotion", "mpu6050_dump"])
def test_a_shipped_example_decodes_its_recording(name: str) -> None:
    assert name in shipped_descriptions()
    decoder = load_decoder(name)
    data = (DATA / f"{name}.bin").read_bytes()
    expected, good = example_stream(name, decoder.description)
    assert data == expected, "tests/data/frames is not what tests/frame_helpers.py generates"
    chunks = [decoder.feed(data[i : i + 61]).samples for i in range(0, len(data), 61)]
    got = np.concatenate([*chunks, decoder.flush().samples])
    stats = decoder.stats
    # The recording: 600 frames of a still unit, frame 10 damaged, frame 20 cut, noise around.
    assert stats.crc_errors == 1 and stats.garbage_bytes > 87
    norm = np.linalg.norm(got["acc"], axis=1)
    rate_hz = decoder.description.rate_hz
    if name == "mpu6050_dump":
        assert len(got) == good == 598 and stats.truncated == 1
        assert np.abs(norm - STANDARD_GRAVITY).max() < 0.2
        steps = np.diff(got["seq"].astype(int))  # the counter shows the two lost samples
        assert sorted(steps)[-2:] == [2, 2] and (steps == 1).sum() == 595
        assert np.all(np.diff(got["t_us"].astype(int)) == steps * 1e6 / rate_hz)
    else:
        # WitMotion checks the rate packet's sum only: the accel packet of cut frame 20 is paired with
        # the accel packet of frame 21 (whose own sum passes), so frame 21 is lost and one sample wrong.
        assert len(got) == 598 and stats.truncated == 0
        assert (np.abs(norm - STANDARD_GRAVITY) > 0.2).sum() == 0
        assert (np.abs(got["gyro"]).max(axis=1) > 0.5).sum() == 1
        assert np.all(np.diff(got["t_us"].astype(int)) == 1e6 / rate_hz)
    assert np.abs(np.median(got["temp"]) - 31.5) < 0.05


@pytest.mark.parametrize(("protocol", "words"), [
    ("frame", "frame needs its description file: frame:FILE.yaml"),
    ("frame:", "frame needs its description file"),
    ("frame:nope.yaml", "nope.yaml: does not exist; give a frame description file (schema "
                        "imu-station/frame/1) or a shipped one: mpu6050_dump, witmotion"),
])
def test_a_frame_protocol_without_a_readable_file_is_a_usage_error(tmp_path: Path, capsys, protocol: str,
                                                                  words: str) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["capture", "--port", "/dev/null-no-such-port", "--protocol", protocol,
              "-o", str(tmp_path / "x.csv")])
    assert stop.value.code == 4 and words in capsys.readouterr().err
