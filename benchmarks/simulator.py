"""Speed of the simulated unit: ``simulate()`` and the pty server at 1 kHz.

1. ``mocks.rig.simulate`` (vectorised) against a plain per-sample Python loop of the same model
   (Rodrigues attitude, M f + b + thermal + white and random-walk noise), the way a naive
   simulator steps: samples per second of each and their ratio, on the same segments.
2. The block path of the served device (``SimDevice.produce`` + the native encoder) at 1 kHz:
   CPU milliseconds per second of stream, i.e. the share of one core the server needs.
3. Sustained serving: ``imu-station simulate --rate 1000`` in its own process, read through a
   real pty with pyserial and the native decoder for ``--seconds`` (default 60): samples
   received against the schedule, samples lost (seq gaps), the rate on the device clock.

Medians of repeats; the machine is shared.

    .venv/bin/python benchmarks/simulator.py [--samples N] [--repeats R] [--seconds S]
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np
import serial
from timing import median_time

from mocks.device import SimDevice
from mocks.rig import Timeline, sequence_segments, simulate
from mocks.truth import UnitTruth
from protocols.native import NativeDecoder


def per_sample_loop(truth: UnitTruth, timeline: Timeline, n: int, rate_hz: float, seed: int) -> np.ndarray:
    """The same unit stepped one sample at a time in Python (the peer): raw acc and gyro (n, 6)."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    acc_m, gyro_m = truth.accel.matrix, truth.gyro.matrix
    out = np.empty((n, 6))
    walk = np.zeros(3)
    gravity = np.array([0.0, 0.0, truth.gravity])
    starts = [p.t0 for p in timeline.pieces]
    for k in range(n):
        t = k * dt
        i = max(0, int(np.searchsorted(starts, t, side="right")) - 1)
        piece = timeline.pieces[i]
        tau = np.array([t - piece.t0])
        phi = float(piece.profile.angle(tau)[0])
        e = piece.axis
        kx = np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])
        rot = np.eye(3) + np.sin(phi) * kx + (1 - np.cos(phi)) * kx @ kx
        force = (piece.r0 @ rot).T @ gravity
        rate = float(piece.profile.rate(tau)[0]) * e
        walk += rng.standard_normal(3) * truth.gyro.noise.K * np.sqrt(dt)
        white_acc = rng.standard_normal(3) * truth.accel.noise.N / np.sqrt(dt)
        white_gyro = rng.standard_normal(3) * truth.gyro.noise.N / np.sqrt(dt)
        out[k, :3] = acc_m @ force + truth.accel.bias + white_acc
        out[k, 3:] = gyro_m @ rate + truth.gyro.bias + walk + white_gyro
    return out


def bench_simulate(samples: int, repeats: int) -> None:
    truth = UnitTruth.random(1)
    segments = sequence_segments("six-position", hold_s=5.0)
    rate_hz = samples / Timeline(segments).duration_s
    n = len(simulate(truth, segments, rate_hz=rate_hz))
    ours = median_time(lambda: simulate(truth, segments, rate_hz=rate_hz, seed=1), repeats)
    n_loop = min(n, 20_000)
    peer = median_time(lambda: per_sample_loop(truth, Timeline(segments), n_loop, rate_hz, 1),
                       max(1, repeats // 2))
    ours_rate, peer_rate = n / ours, n_loop / peer
    print(f"simulate(): {n} samples (six-position with rotations) in {ours * 1e3:.1f} ms = "
          f"{ours_rate / 1e6:.2f} M samples/s")
    print(f"per-sample Python loop (peer): {peer_rate / 1e3:.1f} k samples/s "
          f"-> simulate() is {ours_rate / peer_rate:.0f}x faster")


def bench_blocks(repeats: int) -> None:
    def one_second() -> None:
        device = SimDevice(seed=2, rate_hz=1000, scenario="six-position")
        for k in range(1, 51):  # 50 blocks of 20 ms
            device.encode_samples(device.produce(k * 0.02))

    cpu = []
    for _ in range(repeats):
        t0 = time.process_time()
        one_second()
        cpu.append(time.process_time() - t0)
    ms = statistics.median(cpu) * 1e3
    print(f"served device at 1 kHz, 20 ms blocks: {ms:.1f} ms CPU per second of stream "
          f"({ms / 10:.1f} % of one core)")


def bench_serving(seconds: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        link = os.path.join(tmp, "imu")
        command = [sys.executable, "-m", "station.cli", "simulate", "--rate", "1000", "--seed", "4",
                   "--link", link]
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            while not os.path.lexists(link):
                if proc.poll() is not None:
                    raise SystemExit(f"the simulator exited: {proc.communicate()}")
                time.sleep(0.05)
            decoder = NativeDecoder()
            seqs: list[np.ndarray] = []
            t_first = t_last = None
            with serial.Serial(link, timeout=0.05) as port:
                t0 = time.monotonic()
                while time.monotonic() - t0 < seconds:
                    s = decoder.feed(port.read(max(1, port.in_waiting))).samples
                    if len(s):
                        seqs.append(s["seq"].astype(np.int64))
                        t_first = s["t_us"][0] if t_first is None else t_first
                        t_last = s["t_us"][-1]
                wall = time.monotonic() - t0
            proc.send_signal(signal.SIGINT)
            out, _ = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
    seq = np.concatenate(seqs)
    lost = int(np.sum(np.diff(seq) - 1))
    device_s = (int(t_last) - int(t_first)) / 1e6
    print(f"pty at 1 kHz for {wall:.1f} s: {len(seq)} samples received ({len(seq) / wall:.1f}/s wall, "
          f"{(len(seq) - 1) / device_s:.2f}/s device clock), {lost} lost, "
          f"decoder errors {decoder.stats.errors}")
    print("server: " + " ".join(out.strip().splitlines()[-2:]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=200_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    bench_simulate(args.samples, args.repeats)
    bench_blocks(args.repeats)
    bench_serving(args.seconds)


if __name__ == "__main__":
    main()
