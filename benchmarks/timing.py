"""Timing helpers shared by the benchmark scripts (run as ``.venv/bin/python benchmarks/NAME.py``)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")


def median_time(run: Callable[[], object], repeats: int) -> float:
    """Median wall seconds of ``repeats`` calls of ``run``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def median_wall_cpu(run: Callable[[], T], repeats: int) -> tuple[float, float, T]:
    """Median wall and CPU seconds of ``repeats`` calls of ``run``, and what the last call returned."""
    times, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = run()
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return statistics.median(times), statistics.median(cpu), result


def feed_in_chunks(make_decoder: Callable[[], Any], data: bytes, chunk: int) -> Callable[[], int]:
    """A run that feeds ``data`` to a fresh decoder ``chunk`` bytes at a time, as a reader thread
    does, and returns the samples it gave."""

    def run() -> int:
        decoder = make_decoder()
        count = 0
        for pos in range(0, len(data), chunk):
            count += len(decoder.feed(data[pos : pos + chunk]).samples)
        return count

    return run
