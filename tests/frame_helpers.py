"""Frame descriptions and byte streams for the frame decoder's tests, fuzz line and benchmark.

``python tests/frame_helpers.py`` writes the example boards' recordings in ``tests/data/frames/``
(a still unit, z up, with garbage, a damaged frame and a cut one between good frames); the tests
check that the files are what this module generates.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from protocols.base import SAMPLE_DTYPE
from protocols.frame import encode_frames
from protocols.frame_checksums import checksum_rows
from protocols.frame_description import FrameDescription
from protocols.units import STANDARD_GRAVITY

DATA = Path(__file__).resolve().parent / "data" / "frames"

# The specification's example (shared/specs/frame-description.md), 28 bytes.
SPEC_EXAMPLE = {
    "schema": "imu-station/frame/1", "name": "acme-imu-v2", "byte_order": "little", "sync": [0xAA, 0x55],
    "length": 28, "checksum": {"type": "crc16-ccitt-false", "from": 2, "to": -2, "at": -2}, "rate_hz": 200,
    "fields": [
        {"name": "seq", "at": 2, "type": "u16"},
        {"name": "t", "at": 4, "type": "u32", "scale": 1.0e-6},
        {"name": "ax", "at": 8, "type": "i16", "scale": 0.0023956},
        {"name": "ay", "at": 10, "type": "i16", "scale": 0.0023956},
        {"name": "az", "at": 12, "type": "i16", "scale": 0.0023956},
        {"name": "gx", "at": 14, "type": "i16", "scale": 0.00026632},
        {"name": "gy", "at": 16, "type": "i16", "scale": 0.00026632},
        {"name": "gz", "at": 18, "type": "i16", "scale": 0.00026632},
        {"name": "temp", "at": 20, "type": "i16", "scale": 0.01, "offset": 25.0},
        {"name": "mx", "at": 22, "type": "i16", "scale": 0.15, "byte_order": "big"},
    ],
}


def spec_example(**changes: object) -> dict:
    """The specification's example as plain values, with top-level keys changed (a fresh copy)."""
    doc = {**SPEC_EXAMPLE, "fields": [dict(f) for f in SPEC_EXAMPLE["fields"]],  # type: ignore[union-attr]
           "checksum": dict(SPEC_EXAMPLE["checksum"])}  # type: ignore[arg-type]
    doc.update(changes)
    return doc


# 32-byte frames for the benchmark: the example with a 3-axis magnetometer and a CRC-16 at the end.
BENCH_32 = {
    "schema": "imu-station/frame/1", "name": "bench-32", "sync": [0xAA, 0x55], "length": 32,
    "checksum": {"type": "crc16-ccitt-false"},
    "fields": [
        {"name": "seq", "at": 2, "type": "u16"},
        {"name": "t", "at": 4, "type": "u32", "scale": 1.0e-6},
        *[{"name": n, "at": 8 + 2 * i, "type": "i16", "scale": 0.0023956 if i < 3 else 0.00026632}
          for i, n in enumerate(("ax", "ay", "az", "gx", "gy", "gz"))],
        {"name": "temp", "at": 20, "type": "i16", "scale": 0.01, "offset": 25.0},
        *[{"name": n, "at": 22 + 2 * i, "type": "i16", "scale": 0.15}
          for i, n in enumerate(("mx", "my", "mz"))],
    ],
}


def values_from_samples(desc: FrameDescription, samples: np.ndarray) -> dict[str, np.ndarray]:
    """Physical values of each field of ``desc`` for a batch of ``SAMPLE_DTYPE`` samples."""
    n = len(samples)
    source = {"seq": samples["seq"].astype(np.float64), "t": samples["t_us"].astype(np.float64) / 1e6,
              "temp": samples["temp"].astype(np.float64)}
    for i, axis in enumerate("xyz"):
        source[f"a{axis}"] = samples["acc"][:, i].astype(np.float64)
        source[f"g{axis}"] = samples["gyro"][:, i].astype(np.float64)
        source[f"m{axis}"] = np.full(n, 20.0 * (i + 1))
    return {f.name: source[f.name] for f in desc.fields}


def still_samples(n: int, rate_hz: float, seed: int = 0) -> np.ndarray:
    """A unit lying still, z up: gravity on +z, small biases, noise and a warm board."""
    rng = np.random.default_rng(seed)
    s = np.zeros(n, dtype=SAMPLE_DTYPE)
    s["seq"] = np.arange(n)
    s["t_us"] = np.round(np.arange(n) * 1e6 / rate_hz)
    s["acc"] = np.array([0.05, -0.08, STANDARD_GRAVITY]) + rng.normal(0, 0.02, (n, 3))
    s["gyro"] = np.array([0.002, -0.001, 0.0015]) + rng.normal(0, 0.003, (n, 3))
    s["temp"] = 31.5 + rng.normal(0, 0.05, n)
    return s


def witmotion_frames(desc: FrameDescription, samples: np.ndarray) -> bytes:
    """WitMotion 0x51 + 0x52 packet pairs: the bytes the description does not name are filled in
    as the unit sends them (the second header, the first packet's own sum)."""
    data = bytearray(encode_frames(desc, values_from_samples(desc, samples)))
    rows = np.frombuffer(data, dtype=np.uint8).reshape(len(samples), desc.length).copy()
    rows[:, 11:13] = [0x55, 0x52]
    rows[:, 10] = checksum_rows("sum8", rows[:, 0:10])
    rows[:, 21] = checksum_rows("sum8", rows[:, 11:21])
    return rows.tobytes()


def plain_frames(desc: FrameDescription, samples: np.ndarray) -> bytes:
    """Frames of ``desc`` for the samples, back to back."""
    return encode_frames(desc, values_from_samples(desc, samples))


def damaged_stream(frames: bytes, length: int, seed: int) -> tuple[bytes, int]:
    """``frames`` with noise before them, a flipped byte in frame 10, frame 20 cut short and noise
    after frame 30: ``(stream, good frames left)``."""
    rng = np.random.default_rng(seed)
    pieces = [rng.integers(0, 256, 37, dtype=np.uint8).tobytes()]
    good = 0
    for i in range(len(frames) // length):
        frame = bytearray(frames[i * length : (i + 1) * length])
        if i == 10:
            frame[length // 2] ^= 0x5A
        elif i == 20:
            frame = frame[: length // 2]
        else:
            good += 1
        pieces.append(bytes(frame))
        if i == 30:
            pieces.append(rng.integers(0, 256, 50, dtype=np.uint8).tobytes())
    return b"".join(pieces), good


EXAMPLES = {
    "witmotion": (witmotion_frames, 100.0, 1),
    "mpu6050_dump": (plain_frames, 200.0, 2),
}


def example_stream(name: str, desc: FrameDescription, n: int = 600) -> tuple[bytes, int]:
    """The recording of the shipped example ``name``: ``(bytes, good frames in it)``."""
    encode, rate_hz, seed = EXAMPLES[name]
    return damaged_stream(encode(desc, still_samples(n, rate_hz, seed)), desc.length, seed)


def main() -> None:
    from station.frames.reader import load_description

    DATA.mkdir(parents=True, exist_ok=True)
    for name in EXAMPLES:
        data, _ = example_stream(name, load_description(name))
        (DATA / f"{name}.bin").write_bytes(data)
        print(f"{DATA / name}.bin: {len(data)} bytes")


if __name__ == "__main__":
    main()

