"""Sustained capture from the simulated unit through a pseudo-terminal: lost samples (target 0).

The simulated unit runs in its own process (as a real unit would be on the other side of a
cable) and streams the native protocol on a pty at --rate Hz; this process captures --seconds
of device clock with the station's driver and recorder, as ``imu-station capture`` does, then
checks the file: seq must run without a gap from the first sample to the last. It prints the
samples captured against those the device clock says were due, lost samples, damaged frames,
overflow drops, the CPU the capture used and its peak memory.

    .venv/bin/python benchmarks/capture_rate.py [--rate 1000] [--seconds 60] [--format h5|csv]
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from drivers import open_device
from station.acquisition.capture import read_capture
from station.acquisition.capture_h5 import read_samples
from station.acquisition.recorder import record

SERVER = """
import sys, time
from mocks.pty_server import PtyServer
with PtyServer(seed=1, rate_hz={rate}) as server:
    print(server.port_path, flush=True)
    sys.stdin.read()  # until the benchmark closes our stdin
    print(server.stats.samples_sent, server.stats.samples_overrun, server.stats.late_blocks,
          f"{{server.stats.max_lateness_s:.4f}}", flush=True)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rate", type=int, default=1000, help="sample rate in Hz (default 1000)")
    parser.add_argument("--seconds", type=float, default=60.0, help="seconds of device clock (default 60)")
    parser.add_argument("--format", choices=["h5", "csv"], default="h5", help="capture file format")
    args = parser.parse_args()

    server = subprocess.Popen([sys.executable, "-c", SERVER.format(rate=args.rate)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    port = server.stdout.readline().strip()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"capture.{args.format}"
        cpu0, wall0 = time.process_time(), time.perf_counter()
        with open_device(port) as dev:
            result = record(dev, path, duration_s=args.seconds)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
        server.stdin.close()
        sent, overrun, late_blocks, max_late = server.stdout.readline().split()
        server.wait(10)
        if args.format == "h5":
            got = read_samples(path)
            seq_gaps = int(np.count_nonzero((np.diff(got["seq"].astype(np.int64)) % 2**32) != 1))
            t_us = got["t_us"]
        else:
            cap = read_capture(path)
            t_us = np.round(cap.t * 1e6).astype(np.int64)
            seq_gaps = -1  # the CSV has no seq; the link statistics count the gaps
        due = int(round((int(t_us[-1]) - int(t_us[0])) * 1e-6 * args.rate)) + 1
    link = result.link
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"capture of the simulated unit at {args.rate} Hz through a pty, {args.seconds:g} s of device "
          f"clock, {args.format} file")
    print(f"  samples in the file          {result.rows}")
    print(f"  samples due by device clock  {due}  (file / due = {result.rows / due:.6f})")
    print(f"  lost (seq gaps on the link)  {link.lost}")
    print(f"  seq gaps in the file         {seq_gaps if seq_gaps >= 0 else 'n/a (csv)'}")
    print(f"  damaged frames / garbage     {link.errors} / {link.garbage_bytes} bytes")
    print(f"  overflow drops               {link.overflow_drops}")
    print(f"  rate on the device clock     {link.rate_hz:.2f} Hz")
    print(f"  simulator: sent {sent}, overrun {overrun}, late blocks {late_blocks}, "
          f"max lateness {max_late} s")
    print(f"  capture process: {cpu:.1f} s CPU over {wall:.1f} s wall ({100 * cpu / wall:.1f}% of a core), "
          f"peak RSS {peak_mb:.0f} MB")
    clean = link.lost == 0 and link.overflow_drops == 0 and seq_gaps <= 0
    print("RESULT:", "0 lost" if clean else "SAMPLES LOST")


if __name__ == "__main__":
    main()
