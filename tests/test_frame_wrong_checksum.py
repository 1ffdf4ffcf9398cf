"""A frame description that names the wrong checksum type (issue 31): a board that sends ``xor8`` read with a
description saying ``crc8``. Before, a capture kept the few frames that matched by chance (6 samples in 2 s,
866 CRC errors) and exited 0, and ``frame check`` blamed gz's byte order. Now the capture stops with one line
naming the checksum that fits, ``frame check`` names it too, and its rate and duration count the frames
lost between the good ones."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import yaml
from device_helpers import BytePty
from frame_helpers import SPEC_EXAMPLE, damaged_stream, plain_frames, still_samples

from protocols.frame import CHECKSUM_FAILING_MIN, FrameDecoder
from protocols.frame_checksum_fit import describe_checksum, fitting_checksums
from protocols.frame_description import describe
from station.cli import main
from station.frames.reader import shipped_descriptions

XOR8_LINE = "{type: xor8, from: 2, to: -1, at: -1}"


def _mpu_doc(checksum: dict | None = None) -> dict:
    doc = yaml.safe_load(shipped_descriptions()["mpu6050_dump"].read_text(encoding="utf-8"))
    if checksum is not None:
        doc["checksum"] = checksum
    return doc


def _board_bytes(n: int = 1000, seed: int = 3) -> bytes:
    """What an MPU-6050 forwarding board sends when its sketch computes an XOR of the bytes, not a CRC-8."""
    board = describe(_mpu_doc({"type": "xor8", "from": 2, "to": 17, "at": 17}))
    return plain_frames(board, still_samples(n, 200.0, seed=seed))


def _feed(decoder: FrameDecoder, data: bytes, chunk: int = 97) -> int:
    return sum(len(decoder.feed(data[i : i + chunk]).samples) for i in range(0, len(data), chunk))


def test_the_decoder_names_the_checksum_that_fits_once_most_frames_fail() -> None:
    decoder = FrameDecoder(describe(_mpu_doc()))  # the shipped description: crc8
    data = _board_bytes()
    kept = _feed(decoder, data[: 18 * (CHECKSUM_FAILING_MIN - 5)])
    assert decoder.problem is None  # too few failures yet to say
    kept += _feed(decoder, data[18 * (CHECKSUM_FAILING_MIN - 5) :])
    assert kept < 20 and decoder.stats.crc_errors > 950
    problem = decoder.problem
    assert problem is not None and problem.startswith("frame:mpu6050-dump: ")
    assert "failed the description's checksum {type: crc8, from: 2, to: -1, at: -1}" in problem
    # named as soon as most of the first CHECKSUM_FAILING_MIN or so frames failed
    assert re.search(re.escape(XOR8_LINE) + r" fits (\d+) of the \1 frames refused last", problem), problem
    assert "\n" not in problem


def test_a_right_description_on_a_damaged_link_has_no_problem() -> None:
    desc = describe(SPEC_EXAMPLE)
    decoder = FrameDecoder(desc)
    for seed in range(60):  # a damaged frame and a cut one in every 40: errors, not a wrong description
        stream, _ = damaged_stream(plain_frames(desc, still_samples(40, 200.0, seed=seed)), desc.length, seed)
        _feed(decoder, stream)
    assert decoder.stats.crc_errors >= CHECKSUM_FAILING_MIN and decoder.problem is None


def test_sixteen_bit_checksums_and_byte_orders_are_tried() -> None:
    said = describe(SPEC_EXAMPLE)  # crc16-ccitt-false over 2..-2, little-endian
    board = describe({**SPEC_EXAMPLE, "checksum": {"type": "crc16-xmodem", "from": 2, "to": -2, "at": -2,
                                                   "byte_order": "big"}})
    frames = np.frombuffer(plain_frames(board, still_samples(64, 200.0)), np.uint8).reshape(64, said.length)
    fits = fitting_checksums(said, frames)
    named = describe_checksum(fits[0].spec, said)
    assert named == "{type: crc16-xmodem, from: 2, to: -2, at: -2, byte_order: big}"
    # frames no checksum fits (another board's): none named
    rng = np.random.default_rng(1)
    assert fitting_checksums(said, rng.integers(0, 256, (64, said.length), dtype=np.uint8)) == []


def test_frame_check_names_the_checksum_and_counts_the_lost_frames(tmp_path: Path, capsys) -> None:
    # the specification's example with an 8-bit checksum in its last byte: a 16-bit counter and a clock
    said = {**SPEC_EXAMPLE, "checksum": {"type": "crc8", "from": 2, "to": -1, "at": -1}}
    board = describe({**said, "checksum": {"type": "xor8", "from": 2, "to": -1, "at": -1}})
    desc_file, raw = tmp_path / "board.yaml", tmp_path / "board.bin"
    desc_file.write_text(yaml.safe_dump(said), encoding="utf-8")
    raw.write_bytes(plain_frames(board, still_samples(1000, 200.0, seed=4)))
    code = main(["frame", "check", str(desc_file), "--file", str(raw)])
    out = " ".join(capsys.readouterr().out.split())
    assert code == 1
    assert XOR8_LINE in out and "byte order" not in out and "jumps at random" not in out, out
    # the few frames that passed by chance span most of the 1000 the unit sent at 200 Hz: the duration
    # and the unit's rate count those lost between them (before: 6 frames over 6 s, "1.0/s")
    found = re.search(r"(\d+) frames, [\d.]+/s, (\d+) lost by the counter \(the unit sent 200\.0/s\);.* "
                      r"([\d.]+) s ┏", out)
    assert found is not None, out
    sent = int(found.group(1)) + int(found.group(2))
    assert sent > 500 and abs(float(found.group(3)) - sent / 200.0) <= 0.05


def test_a_capture_with_the_wrong_checksum_type_stops_with_one_line(tmp_path: Path, capsys) -> None:
    desc_file = tmp_path / "board.yaml"
    desc_file.write_text(yaml.safe_dump(_mpu_doc()), encoding="utf-8")
    out = tmp_path / "cap.csv"
    data = _board_bytes(2000)
    with BytePty.chunked(data, chunk=10 * 18, period_s=0.05) as pty:
        code = main(["capture", "--port", pty.path, "--protocol", f"frame:{desc_file}", "--duration", "10",
                     "-o", str(out)])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "error:" in line]
    assert code == 4, err
    assert len(lines) == 1 and XOR8_LINE in lines[0] and "the capture stopped" in lines[0], err
