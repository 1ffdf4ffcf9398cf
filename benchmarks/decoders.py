"""Every decoder's speed against its target, and the CPU of a frame-by-frame capture, in one run.

Part 1, the table: each decoder (native, a frame description, Xsens MTData2, MAVLink HIGHRES_IMU,
text lines: CSV, MotionCal ``Raw:`` and ``Uni:``, VectorNav ``$VNYMR`` and ``$VNIMU``) decodes a
stream of its own frames, clean and with one frame (line) in a hundred damaged (a byte in its
middle flipped), fed in 4 KiB chunks (a serial read at a few hundred kbit/s)
and in 64 KiB chunks (a USB-CDC burst). Frames (lines) per CPU second of this process, median of
``--repeats`` runs, and the ratio to the target: 1,000,000 frames/s for the binary protocols,
300,000 lines/s for text. A slow decoder is timed on fewer frames (a run of about 0.3 s): its rate
is per frame.

Part 2, the capture: a simulated 200 Hz unit on a pty (``mocks.pty_server`` in a process of its
own, one frame per ``os.write``: a block period of one sample) at ``--speed`` times its clock, captured
for ``--seconds`` of device clock with the station's driver and recorder (``open_device`` +
``record``, as ``imu-station capture`` does), once through the native protocol and once through a
frame description, to CSV and to HDF5. The CPU of the capturing process (reader thread, decoder,
recorder, file) and the ratio frame description / native (target at most 1.3).

The machine may be shared: times are CPU seconds of this process, and ``uptime``'s load is printed.

    .venv/bin/python benchmarks/decoders.py [--frames N] [--repeats R] [--speed S] [--seconds T]
                                            [--skip-table] [--skip-capture]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml
from frame_decode import DESCRIPTION, make_samples  # the 32-byte board frame both benchmarks decode

from protocols import ascii_lines, mavlink, native, xsens
from protocols.base import StreamDecoderBase
from protocols.frame import FrameDecoder, encode_frames
from protocols.frame_description import describe

BINARY_TARGET = 1_000_000
TEXT_TARGET = 300_000
CHUNKS = (4096, 65536)
DAMAGE_EVERY = 100

# ------------------------------------------------------------------------------------- streams


def _frame_bytes(s: np.ndarray) -> bytes:
    desc = describe(DESCRIPTION)
    values = {"seq": s["seq"] % 65536, "t": (s["t_us"] % 2**32) * 1e-6, "temp": s["temp"],
              **{f"a{a}": s["acc"][:, i] for i, a in enumerate("xyz")},
              **{f"g{a}": s["gyro"][:, i] for i, a in enumerate("xyz")},
              **{f"m{a}": np.full(len(s), 20.0) for a in "xyz"}}
    return encode_frames(desc, values)


def _walk(stream: bytes, length_at: Callable[[bytes, int], int]) -> np.ndarray:
    """Frame starts of a clean stream of back-to-back frames, each frame's length read at its start."""
    starts, pos = [], 0
    while pos < len(stream):
        starts.append(pos)
        pos += length_at(stream, pos)
    return np.array(starts)


def _xsens_length(b: bytes, p: int) -> int:
    return 7 + ((b[p + 4] << 8) | b[p + 5]) if b[p + 3] == 0xFF else 5 + b[p + 3]


def _mavlink_length(b: bytes, p: int) -> int:
    return (8 if b[p] == mavlink.STX_V1 else 12) + b[p + 1]


class Protocol:
    """One row group of the table: how to encode samples, find the frames, and make the decoder."""

    def __init__(self, name: str, unit: str, target: int, encode: Callable[[np.ndarray], bytes],
                 starts: Callable[[bytes], np.ndarray], decoder: Callable[[], StreamDecoderBase]):
        self.name, self.unit, self.target = name, unit, target
        self.encode, self.starts, self.decoder = encode, starts, decoder


def protocols() -> list[Protocol]:
    desc = describe(DESCRIPTION)
    found = [
        Protocol("native", "frames", BINARY_TARGET, native.encode_samples,
                 lambda b: np.arange(0, len(b), native.SAMPLE_FRAME_SIZE), native.NativeDecoder),
        Protocol("frame description", "frames", BINARY_TARGET, _frame_bytes,
                 lambda b: np.arange(0, len(b), desc.length), lambda: FrameDecoder(desc)),
        Protocol("xsens MTData2", "frames", BINARY_TARGET, xsens.encode_samples,
                 lambda b: _walk(b, _xsens_length), xsens.XsensDecoder),
    ]
    if mavlink.pymavlink_available():
        found.append(Protocol("mavlink HIGHRES_IMU", "frames", BINARY_TARGET,
                              lambda s: mavlink.encode_samples(s, "HIGHRES_IMU"),
                              lambda b: _walk(b, _mavlink_length), mavlink.MavlinkDecoder))
    dialects = (("CSV lines", ascii_lines.encode_csv),
                ("Raw:", ascii_lines.encode_motioncal),
                ("Uni:", _encode_uni),
                ("$VNYMR", lambda s: ascii_lines.encode_vectornav(s, "VNYMR")),
                ("$VNIMU", lambda s: ascii_lines.encode_vectornav(s, "VNIMU")))
    found.extend(Protocol(f"text ({label})", "lines", TEXT_TARGET, encode, _line_starts,
                          ascii_lines.AsciiDecoder) for label, encode in dialects)
    return found


def _line_starts(b: bytes) -> np.ndarray:
    return np.flatnonzero(np.frombuffer(b"\n" + b[:-1], np.uint8) == 10)


def _encode_uni(s: np.ndarray) -> bytes:
    """Adafruit's ``Uni:`` lines (m/s^2, rad/s, uT; a constant field): no package encoder writes them."""
    return "".join(f"Uni:{a[0]:.4f},{a[1]:.4f},{a[2]:.4f},{g[0]:.5f},{g[1]:.5f},{g[2]:.5f},"
                   "20.00,0.00,-40.00\r\n" for a, g in zip(s["acc"], s["gyro"], strict=True)).encode("ascii")


def damage(stream: bytes, starts: np.ndarray, every: int) -> bytes:
    """Flip (XOR 0x5A) the byte in the middle of one frame in ``every``."""
    out = np.frombuffer(stream, dtype=np.uint8).copy()
    ends = np.append(starts[1:], len(stream))
    hit = (starts + ends)[::every] // 2
    out[hit] ^= 0x5A
    return out.tobytes()


# ------------------------------------------------------------------------------------- timing


def decode_run(make: Callable[[], StreamDecoderBase], data: bytes, chunk: int) -> int:
    """Frames the decoder gave for ``data`` fed ``chunk`` bytes at a time, then flushed."""
    dec = make()
    n = 0
    for pos in range(0, len(data), chunk):
        n += len(dec.feed(data[pos : pos + chunk]))
    return n + len(dec.flush())


def cpu_rate(make: Callable[[], StreamDecoderBase], data: bytes, frames: int, chunk: int,
             repeats: int) -> float:
    """Frames per CPU second, median of ``repeats`` runs."""
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        decode_run(make, data, chunk)
        times.append(time.process_time() - t0)
    return frames / statistics.median(times)


def table(n_frames: int, repeats: int) -> list[tuple[str, str, int, float, float]]:
    """Print (and return) the table: decoder, stream, chunk, rate, ratio to the target."""
    print(f"decoders, frames (lines) per CPU second, median of {repeats}, up to {n_frames} frames a stream")
    print(f"{'decoder':<22}{'stream':<12}{'chunk':>7}{'per second':>14}{'target':>11}{'ratio':>8}")
    rows = []
    samples = make_samples(n_frames)
    for proto in protocols():
        # A short stream first: a slow decoder is timed on about 0.3 s worth of frames.
        probe_n = min(n_frames, 20_000)
        probe = proto.encode(samples[:probe_n])
        t0 = time.process_time()
        decode_run(proto.decoder, probe, CHUNKS[0])
        probe_rate = probe_n / max(time.process_time() - t0, 1e-6)
        n = int(min(n_frames, max(probe_n, probe_rate * 0.3)))
        clean = probe if n == probe_n else proto.encode(samples[:n])
        starts = proto.starts(clean)
        assert len(starts) == n, (proto.name, len(starts), n)
        for label, data in (("clean", clean), ("1% damaged", damage(clean, starts, DAMAGE_EVERY))):
            for chunk in CHUNKS:
                rate = cpu_rate(proto.decoder, data, n, chunk, repeats)
                ratio = rate / proto.target
                rows.append((proto.name, label, chunk, rate, ratio))
                print(f"{proto.name:<22}{label:<12}{chunk:>7}{rate:>14,.0f}{proto.target:>11,}"
                      f"{ratio:>7.2f}x{'' if ratio >= 1 else '  MISS'}", flush=True)
    return rows


# ------------------------------------------------------------------------------------- capture

SERVER = """
import sys
from mocks.device import SimDevice
from mocks.frame_unit import speak_frames
from mocks.pty_server import PtyServer
from protocols.frame_description import describe
import yaml
device = SimDevice(seed=1, rate_hz={rate})
if {frame!r}:
    speak_frames(device, describe(yaml.safe_load(open({desc_path!r}))))
with PtyServer(device, block_s={block_s}, speed={speed}) as server:
    print(server.port_path, flush=True)
    sys.stdin.read()
    print(server.stats.samples_sent, server.stats.bytes_written, server.stats.late_blocks, flush=True)
"""


def capture_cpu(protocol: str, desc_path: Path, fmt: str, rate_hz: float, speed: float,
                seconds: float, tmp: Path) -> tuple[float, int, float]:
    """CPU seconds of capturing ``seconds`` of device clock, the rows written, and writes per frame."""
    import station.frames.reader  # noqa: F401  (installs the frame-description reader, as the CLI does)
    from drivers import open_device
    from station.acquisition.recorder import record

    frame = protocol != "native"
    code = SERVER.format(rate=rate_hz, frame=frame, desc_path=str(desc_path),
                         block_s=1.0 / (rate_hz * speed), speed=speed)
    server = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True, cwd=Path(__file__).resolve().parent.parent)
    assert server.stdout is not None and server.stdin is not None
    port = server.stdout.readline().strip()
    path = tmp / f"capture-{protocol.partition(':')[0]}.{fmt}"
    try:
        cpu0 = time.process_time()
        with open_device(port, protocol=protocol) as dev:
            result = record(dev, path, duration_s=seconds)
            reads = dev.stats.bytes
        cpu = time.process_time() - cpu0
    finally:
        server.stdin.close()
        sent, written, late = server.stdout.readline().split()
        server.wait(10)
    path.unlink(missing_ok=True)
    del reads, written
    return cpu, result.rows, int(late) / max(int(sent), 1)


def capture(speed: float, seconds: float, repeats: int) -> list[tuple[str, float, float, float]]:
    print(f"\ncapture of a 200 Hz unit writing one frame per write, {seconds:g} s of device clock at "
          f"speed {speed:g} ({seconds / speed:.1f} s wall), CPU seconds of the capturing process, "
          f"median of {repeats}")
    print(f"{'file':<6}{'native':>10}{'frame desc.':>13}{'ratio':>8}{'rows n/f':>16}")
    rows = []
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        desc_path = tmp / "bench-32.yaml"
        desc_path.write_text(yaml.safe_dump(DESCRIPTION), encoding="utf-8")
        for fmt in ("csv", "h5"):
            cpu: dict[str, list[float]] = {"native": [], "frame": []}
            got: dict[str, int] = {}
            for _ in range(repeats):  # alternated: the machine's load varies
                for kind, protocol in (("native", "native"), ("frame", f"frame:{desc_path}")):
                    c, n, _ = capture_cpu(protocol, desc_path, fmt, 200.0, speed, seconds, tmp)
                    cpu[kind].append(c)
                    got[kind] = n
            med = {k: statistics.median(v) for k, v in cpu.items()}
            ratio = med["frame"] / med["native"]
            rows.append((fmt, med["native"], med["frame"], ratio))
            print(f"{fmt:<6}{med['native']:>9.2f}s{med['frame']:>12.2f}s{ratio:>7.2f}x"
                  f"{got['native']:>8}/{got['frame']:<7}{'' if ratio <= 1.3 else '  MISS'}", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200_000, help="frames a stream (fewer: slow decoders)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--speed", type=float, default=5.0, help="device clock / wall clock of the capture")
    parser.add_argument("--seconds", type=float, default=30.0, help="device seconds a capture")
    parser.add_argument("--capture-repeats", type=int, default=3)
    parser.add_argument("--skip-table", action="store_true")
    parser.add_argument("--skip-capture", action="store_true")
    args = parser.parse_args()
    print("load:", os.getloadavg(), "cpus:", os.cpu_count())
    if not args.skip_table:
        table(args.frames, args.repeats)
    if not args.skip_capture:
        capture(args.speed, args.seconds, args.capture_repeats)
    print("load:", os.getloadavg())


if __name__ == "__main__":
    main()
