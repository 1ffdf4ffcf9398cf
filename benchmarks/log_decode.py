"""Decode speed of a 100 MB PX4 ULog: the station's reader against pyulog's own read of the same file.

The log is a simulated three-IMU board (``sensor_accel`` and ``sensor_gyro``, multi_id 0..2, 1 kHz each,
interleaved by timestamp as PX4's logger writes them) made with ``mocks/ulog_writer.py``. Timed, each a
fresh read of the whole file (page cache warm after the first):

- ours: ``station.acquisition.ulog_reader.read_ulog`` (the two topics decoded: numba walks the message
  headers, numpy views each topic's payloads), and ``autopilot_log.open_log(...).captures()`` (the
  same, then every IMU as a Capture: pairing, float64 arrays, notes);
- pyulog 1.3.0: ``ULog(path, ["sensor_accel", "sensor_gyro"])`` and ``ULog(path)`` (every topic).

Before timing, every instance's samples are checked equal to pyulog's (counts, timestamps, x, y, z,
temperature), so the speed is of the same result. Samples/s counts sensor samples (accel and gyro
each); medians of ``--repeats``, the readers alternated (the machine may be shared), the first call of
ours reported apart (it loads numba and its cached kernels). The load average is printed.

    .venv/bin/python benchmarks/log_decode.py [--mb 100] [--repeats 5] [--keep FILE.ulg]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from mocks.ulog_writer import SENSOR_ACCEL, SENSOR_GYRO, Topic, records, write_ulog  # noqa: E402

RATE_HZ = 1000.0
INSTANCES = 3
ACCEL_IDS = (1310988, 1310996, 1311004)
GYRO_IDS = (2359308, 2359316, 2359324)


def make_log(path: Path, megabytes: float) -> int:
    """A three-IMU ULog of about ``megabytes``; returns the samples per topic."""
    per_tick = 2 * INSTANCES * (5 + 44)  # a D message: 3-byte header, msg_id, 44 bytes of fields
    n = int(megabytes * 1e6 / per_tick)
    rng = np.random.default_rng(0)
    t_us = (np.arange(n) * (1e6 / RATE_HZ)).astype(np.uint64) + 1_000_000
    temp = np.linspace(10.0, 60.0, n, dtype=np.float32)
    topics = []
    for i in range(INSTANCES):
        for name, fields, dev, scale in (("sensor_accel", SENSOR_ACCEL, ACCEL_IDS[i], 0.05),
                                         ("sensor_gyro", SENSOR_GYRO, GYRO_IDS[i], 0.01)):
            values = rng.normal(0.0, scale, (n, 3)).astype(np.float32)
            rec = records(fields, n, timestamp=t_us + 150 + i, timestamp_sample=t_us + i, device_id=dev,
                          x=values[:, 0], y=values[:, 1], z=values[:, 2], temperature=temp, samples=1)
            topics.append(Topic(name, i, fields, rec))
    write_ulog(path, topics, {"TC_A_ENABLE": 1, "SENS_BOARD_ROT": 0}, info={"sys_name": "PX4",
                                                                         "ver_hw": "BENCH"})
    return n


def check_same(path: Path) -> int:
    """Every instance's samples as pyulog reads them; returns the sensor samples checked."""
    from pyulog import ULog

    from station.acquisition.ulog_reader import read_ulog

    ours = read_ulog(path)
    total = 0
    for data in ULog(str(path), ["sensor_accel", "sensor_gyro"]).data_list:
        mine = ours.topics[data.name, data.multi_id]
        for field in ("timestamp", "timestamp_sample", "device_id", "x", "y", "z", "temperature"):
            if not np.array_equal(mine[field], data.data[field]):
                raise SystemExit(f"{data.name} {data.multi_id} {field}: our samples differ from pyulog's")
        total += len(mine)
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mb", type=float, default=100.0, help="size of the log (default 100 MB)")
    parser.add_argument("--repeats", type=int, default=5, help="timed reads of each kind (default 5)")
    parser.add_argument("--keep", type=Path, help="write the log here and keep it")
    args = parser.parse_args()

    from pyulog import ULog

    from station.acquisition.autopilot_log import open_log
    from station.acquisition.ulog_reader import read_ulog

    with tempfile.TemporaryDirectory(prefix="imu-log-decode-") as tmp:
        path = args.keep or Path(tmp) / "board.ulg"
        start = time.perf_counter()
        n = make_log(path, args.mb)
        print(f"log: {path.stat().st_size / 1e6:.1f} MB, {INSTANCES} IMUs x (sensor_accel + sensor_gyro) "
              f"x {n} samples at {RATE_HZ:g} Hz ({time.perf_counter() - start:.1f} s to write)")
        start = time.perf_counter()
        read_ulog(path)
        first = time.perf_counter() - start
        samples = check_same(path)
        print(f"samples: {samples} sensor samples, each equal to pyulog's (timestamps, device ids, x, y, z, "
              "temperature)")
        readers = {
            "ours: read_ulog (sensor_accel, sensor_gyro)": lambda: read_ulog(path),
            "ours: open_log(...).captures() (3 Captures)": lambda: open_log(path).captures(),
            "pyulog: ULog(path, [sensor_accel, sensor_gyro])": lambda: ULog(str(path),
                                                                            ["sensor_accel", "sensor_gyro"]),
            "pyulog: ULog(path) (every topic)": lambda: ULog(str(path)),
        }
        times: dict[str, list[float]] = {name: [] for name in readers}
        load = []
        for _ in range(args.repeats):
            for name, read in readers.items():
                start = time.perf_counter()
                read()
                times[name].append(time.perf_counter() - start)
            load.append(os.getloadavg()[0])
    medians = {name: statistics.median(values) for name, values in times.items()}
    reference = medians["pyulog: ULog(path, [sensor_accel, sensor_gyro])"]
    print(f"\n{'reader':50} {'median s':>9} {'Msamples/s':>11} {'x pyulog':>9}")
    for name, seconds in medians.items():
        print(f"{name:50} {seconds:9.3f} {samples / seconds / 1e6:11.2f} {reference / seconds:9.2f}")
    print(f"\nfirst read_ulog of the process: {first:.3f} s (numba and its cached kernels loaded; the first "
          "run after an install compiles them)")
    print(f"medians of {args.repeats}; load average while measuring {statistics.median(load):.2f} on "
          f"{os.cpu_count()} cores")


if __name__ == "__main__":
    main()
