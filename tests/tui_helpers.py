"""Helpers of the TUI tests: waiting on the headless app, and comparing SVG screenshots by their text."""

from __future__ import annotations

import html
import os
import re
import time
from collections.abc import Callable
from pathlib import Path

SNAPSHOTS = Path(__file__).parent / "snapshots"
_TEXT = re.compile(r'<text[^>]*\sx="([\d.]+)"[^>]*\sy="([\d.]+)"[^>]*>(.*?)</text>', re.S)
_SIZE = re.compile(r'<svg[^>]*viewBox="0 0 ([\d.]+) ([\d.]+)"')
_SPACES = re.compile(r" {2,}")
_NUMBER = re.compile(r"[+-]?\d+(?:\.\d+)?(?:e[+-]?\d+)?")


async def wait_for(pilot, condition: Callable[[], object], timeout_s: float, what: str, step_s: float = 0.1):
    """Let the app run until ``condition()`` is true; fail naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        await pilot.pause(step_s)


async def answer_every_prompt(pilot, wizard) -> None:
    """Answer each of the wizard's prompts (start, any review) with Enter until its run ends."""
    while wizard.result is None:
        await wait_for(pilot, lambda: wizard.prompt is not None or wizard.result is not None, 150,
                       "a prompt or the end of the run")
        if wizard.prompt is not None:
            await pilot.press("enter")
            await pilot.pause(0.2)


async def stop_reader(pilot, screen) -> None:
    """Stop ``screen``'s reader worker and wait until it has ended (a thread worker only sees its
    cancellation between reads, so a snapshot of the unit could otherwise come after one a test posts),
    then let what it posted before be shown."""
    readers = [w for w in screen.workers if w.group == "reader" and w.node is screen]
    screen.workers.cancel_group(screen, "reader")
    await wait_for(pilot, lambda: all(w.is_finished for w in readers), 20, "the reader to end")
    await pilot.pause(0.3)


def svg_rows(svg: str) -> list[str]:
    """The screen's text, one string per row, from a textual SVG screenshot (styles ignored)."""
    rows: dict[float, list[tuple[float, str]]] = {}
    for x, y, body in _TEXT.findall(svg):
        text = html.unescape(re.sub(r"<[^>]+>", "", body)).replace("\xa0", " ")
        rows.setdefault(float(y), []).append((float(x), text))
    return ["".join(t for _, t in sorted(parts)).rstrip() for _, parts in sorted(rows.items())]


def structure(rows: list[str]) -> list[str]:
    """Rows with every number replaced by '#' and runs of spaces by one: layout, labels and verdicts, not
    float round-off or the width of a number (a pty's /dev/pts/9 against /dev/pts/12 shifts a column)."""
    return [_SPACES.sub(" ", _NUMBER.sub("#", row)) for row in rows]


def svg_size(svg: str) -> tuple[str, str]:
    m = _SIZE.search(svg)
    assert m, "not a textual SVG screenshot"
    return m.group(1), m.group(2)


def _snapshot_difference(svg: str, name: str) -> str | None:
    """What differs between ``svg`` and ``tests/snapshots/<name>.svg`` (size, and the structure of its
    text rows with numbers masked: values are checked by the tests themselves), None if nothing does;
    UPDATE_SNAPSHOTS=1 rewrites the snapshot."""
    path = SNAPSHOTS / f"{name}.svg"
    if os.environ.get("UPDATE_SNAPSHOTS") == "1" or not path.exists():
        if not path.exists() and os.environ.get("UPDATE_SNAPSHOTS") != "1":
            raise AssertionError(f"no snapshot {path}; run with UPDATE_SNAPSHOTS=1 to create it, then "
                                 "review it")
        path.write_text(svg, encoding="utf-8")
        return None
    expected = path.read_text(encoding="utf-8")
    if svg_size(svg) != svg_size(expected):
        return f"{name}: screen size changed"
    got, want = structure(svg_rows(svg)), structure(svg_rows(expected))
    diff = [f"row {i}: expected {w!r}\n        got      {g!r}"
            for i, (g, w) in enumerate(zip(got, want, strict=False)) if g != w]
    if len(got) == len(want) and not diff:
        return None
    return f"{name} differs from {path}:\n" + "\n".join(diff[:10])


async def expect_snapshot(pilot, app, name: str, timeout_s: float = 10.0) -> None:
    """Wait until the app's screen matches ``tests/snapshots/<name>.svg``; fail with the rows that
    still differ after ``timeout_s``. A screen is drawn a moment after its state changes, later on a
    loaded machine, so one screenshot taken after a fixed pause may catch the previous frame."""
    deadline = time.monotonic() + timeout_s
    while True:
        difference = _snapshot_difference(app.export_screenshot(), name)
        if difference is None:
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"after {timeout_s} s: {difference}")
        await pilot.pause(0.2)


def ideal_run(hold_s: float = 1.0):
    """A completed six-position run with rotations of an ideal simulated unit (100 Hz, serial SIM-IDEAL)."""
    from mocks.rig import sequence_segments, simulate
    from mocks.truth import UnitTruth
    from station.acquisition.runner import RunResult
    from station.acquisition.sequences import builtin

    segments = sequence_segments("six-position", hold_s=hold_s, rotation_rate_dps=180.0)
    capture = simulate(UnitTruth.ideal(), segments, rate_hz=100.0).to_capture()
    capture.device = {"serial": "SIM-IDEAL", "model": "imu-sim", "firmware": "1.0.0", "rate_hz": 100}
    return RunResult("completed", capture, [], builtin("six-position"))


async def results_ready(pilot, app, run):
    """Show ``run``'s results on ``app`` (from its connect screen) and wait for the calibration."""
    from station.tui.screens.results import ResultsScreen

    await wait_for(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 5, "the connect screen")
    await pilot.pause(0.2)
    app.show_results(run)
    screen = await wait_for(pilot, lambda: isinstance(app.screen, ResultsScreen) and app.screen, 5, "results")
    await wait_for(pilot, lambda: screen.report is not None, 30, "the calibration")
    await pilot.pause(0.2)
    return screen


def screen_text(app) -> str:
    """What the app's screen shows, as text rows."""
    return "\n".join(svg_rows(app.export_screenshot()))


def shown(app, words: str, sep: str = "\n") -> str | None:
    """The screen's rows joined by ``sep`` once they show ``words``, else None: a condition for
    :func:`wait_for`, since a screen is drawn a moment after its state changes (a loaded machine shows
    the gap)."""
    text = sep.join(svg_rows(app.export_screenshot()))
    return text if words in text else None
