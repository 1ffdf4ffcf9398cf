"""Turn-on repeatability: the unit recorded still over several power-ups, then the spread of its biases.

Before each record but the first the unit is restarted with RESTART; a unit that answers ACK status 1
cannot restart itself, and a prompt asks the operator to power-cycle it (its serial link stays open:
a unit powered apart from its link, such as a board behind a USB-serial adapter) and press Enter.

With ``--supply`` the unit is power-cycled through its bench supply instead, RESTART and the operator
left out (:class:`~station.instruments.power_cycle.SupplyPowerCycle`: output off, held ``--supply-off``,
on), and the screen says each switch as it happens; the record starts once the unit streams again. A
supply that fails (or a unit that does not come back) stops the turn-ons with the reason on the screen;
Enter computes from the records made.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
from rich.text import Text
from textual import work
from textual.widgets import Static
from textual.worker import get_current_worker

from drivers.errors import DriverError
from station.acquisition.turn_ons import restart_unit
from station.engines.characterisation.turn_on import reduce_record, turn_on_repeatability
from station.errors import StationError
from station.export.params.characterisation import merged, repeatability_keys
from station.export.params.file import ParamsFile
from station.report.datasheet import datasheet_rows, format_table
from station.tui.messages import LinkFailed, Snapshot
from station.tui.plot import Series, draw
from station.tui.screens.ask import AskScreen
from station.tui.screens.long_recording import LongRecordingScreen

COLORS = ("red", "green", "blue")
TURN_ONS = 5
STILL_S = 30.0
UI_PERIOD_S = 0.25
SAMPLES_BACK_S = 10.0  # wall seconds a unit may take to boot and stream after its supply comes on


class _SupplyFailed(Exception):
    """The supply could not power-cycle the unit, or the unit did not stream again: why, in one line."""


class TurnOnsScreen(LongRecordingScreen):
    """``turn_ons`` still records of ``still_s`` device seconds, one per power-up; then eq. (1)-(3) of
    ``characterisation_turnon`` and the ``characterisation`` section (its other keys kept)."""

    HEADING = "Turn-on repeatability"
    KIND = "turn-ons"
    SECTION = "characterisation"
    INTRO = "Keep the unit still in one pose: it is restarted between records."
    FITTING = "computing the turn-on repeatability ..."

    def __init__(self, turn_ons: int = TURN_ONS, still_s: float = STILL_S) -> None:
        super().__init__()
        self.supply_failed: str | None = None
        self.turn_ons = turn_ons
        self.still_s = still_s
        self.records: list[np.ndarray] = []
        self._powered = threading.Event()
        self._abandoned = False

    def on_mount(self) -> None:
        """Say how the unit is restarted (through the supply with --supply); the base class's handler,
        which textual calls after this one, starts the recording."""
        power = self.session.power
        if power is not None:
            self.query_one("#side", Static).update(f"Keep the unit still in one pose: it is power-cycled "
                                                   f"through {power.supply.url} between records.")

    @work(thread=True, exclusive=True, group="reader")
    def _read(self) -> None:
        worker = get_current_worker()
        device = self.session.device
        try:
            for k in range(self.turn_ons):
                try:
                    if k and not self._restart(device, k):
                        break
                except _SupplyFailed as failed:
                    self.post_message(Snapshot({"supply_failed": str(failed)}))
                    return  # the reason stays on the screen; Enter computes from the records made
                batches: list[np.ndarray] = []
                count, last = 0, 0.0
                device.read(0)  # the old power-up's samples
                while not worker.is_cancelled:
                    batch = device.read(0.05)
                    if len(batch):
                        batches.append(batch)
                        self.recording.add(batch)
                        count += len(batch)
                    got = np.concatenate(batches) if batches else batch
                    elapsed = (float(got["t_us"][-1]) - float(got["t_us"][0])) * 1e-6 if count > 1 else 0.0
                    if time.monotonic() - last >= UI_PERIOD_S or elapsed >= self.still_s:
                        last = time.monotonic()
                        self.post_message(Snapshot({"turn_on": k, "elapsed": elapsed, "count": count}))
                    if elapsed >= self.still_s:
                        self.records.append(got)
                        break
                if worker.is_cancelled:
                    return
            self.post_message(Snapshot({"done": True}))  # all recorded, or the operator stopped
        except DriverError as exc:
            self.post_message(LinkFailed(exc))

    def _restart(self, device: Any, k: int) -> bool:
        """Restart the unit for turn-on ``k`` (through its supply with --supply), or have the operator
        power-cycle it; False if abandoned."""
        power = self.session.power
        if power is not None:
            self._supply_cycle(power, device, k)
            return not self._abandoned
        if restart_unit(device):
            return True
        self._powered.clear()
        self.post_message(Snapshot({"power_cycle": k}))
        self._powered.wait()
        return not self._abandoned

    def _supply_cycle(self, power: Any, device: Any, k: int) -> None:
        """Power-cycle the unit through ``power`` (a SupplyPowerCycle) for turn-on ``k``, saying each
        switch on the screen, and wait for its samples; :class:`_SupplyFailed` when either fails."""
        url = power.supply.url
        self.post_message(Snapshot({"supply": k, "doing": f"{url}: output off, held off {power.off_s:g} s, "
                                                          "then on again"}))
        try:
            power(k + 1)
            volts, amps = power.supply.voltage_v(), power.supply.current_a()
        except (StationError, OSError) as exc:  # an instrument's errors are StationErrors
            raise _SupplyFailed(f"the supply failed at turn-on {k + 1}: {exc}") from None
        self.post_message(Snapshot({"supply": k, "doing": f"{url}: output on ({volts:.2f} V, {amps:.3f} A); "
                                                          "waiting for the unit's samples"}))
        device.read(0)  # the old power-up's samples, all in before the output went off
        deadline = time.monotonic() + SAMPLES_BACK_S
        worker = get_current_worker()
        while not worker.is_cancelled and not self._abandoned:
            if len(device.read(0.1)):
                return
            if time.monotonic() > deadline:
                raise _SupplyFailed(f"no samples from the unit {SAMPLES_BACK_S:g} s after {url} switched "
                                   f"it on (turn-on {k + 1}); check its wiring to the supply, the voltage "
                                   "(--supply-volts) and the current limit (--supply-amps)")

    def show_progress(self, d: dict[str, Any]) -> None:
        """The turn-on being recorded, the supply's switching, or the power-cycle prompt; the means so far."""
        if d.get("done"):
            self.action_stop()
            return
        if "power_cycle" in d:
            self._ask_power_cycle(d["power_cycle"])
            return
        if "supply_failed" in d:
            self.supply_failed = d["supply_failed"]
            side = Text(f"{d['supply_failed']}\n", style="red")
            side.append(f"{len(self.records)} turn-on(s) recorded. Enter: compute from them · Escape: back",
                        style="bold")
            self.query_one("#side", Static).update(side)
            return
        power = self.session.power
        if "supply" in d:
            side = Text()
            side.append(f"turn-on {d['supply'] + 1} of {self.turn_ons}  ", style="bold")
            side.append("power-cycling the unit through its supply\n")
            side.append(f"{d['doing']}\n", style="cyan")
            side.append("Enter: stop and compute from the turn-ons recorded · Escape: back", style="bold")
            self.query_one("#side", Static).update(side)
            return
        side = Text()
        side.append(f"turn-on {d['turn_on'] + 1} of {self.turn_ons}  ", style="bold")
        side.append(f"{d['elapsed']:.1f} s of {self.still_s:g} s still, {d['count']} samples\n")
        how = f"power-cycled through {power.supply.url}" if power is not None else "restarted"
        side.append(f"Keep the unit still in one pose; it is {how} before each record.\n")
        side.append("Enter: stop and compute from the turn-ons recorded · Escape: back", style="bold")
        self.query_one("#side", Static).update(side)
        self._draw_means()

    def _ask_power_cycle(self, k: int) -> None:
        def answered(reply: tuple[str, str] | None) -> None:
            self._abandoned = reply is None or reply[0] != "c"
            self._powered.set()

        self.app.push_screen(AskScreen(
            f"Turn-on {k + 1}: the unit cannot restart itself (RESTART answered status 1). Switch it off, "
            "wait a few seconds, switch it on, then press Enter.",
            [("c", "it is back on: record"), ("x", "stop here")]), answered)

    def _draw_means(self) -> None:
        records = list(self.records)  # one copy: the reader thread may append a record meanwhile
        if not records:
            return
        gyro = np.array([r["gyro"].astype(float).mean(axis=0) for r in records])
        acc = np.array([r["acc"].astype(float).mean(axis=0) for r in records])
        x = np.arange(1, len(records) + 1, dtype=float)
        gyro_plot, acc_plot = self.plots()
        draw(gyro_plot, [Series(f"g{a}", x, (gyro[:, j] - gyro[:, j].mean()) * 180 / np.pi, COLORS[j])
                         for j, a in enumerate("xyz")],
             title="gyro mean - its average", xlabel="turn-on", ylabel="deg/s")
        draw(acc_plot, [Series(f"a{a}", x, acc[:, j] - acc[:, j].mean(), COLORS[j])
                        for j, a in enumerate("xyz")],
             title="accel mean - its average", xlabel="turn-on", ylabel="m/s^2")

    def on_unmount(self) -> None:
        """Leaving the screen abandons a pending power-cycle prompt (the reader must not wait on)."""
        self._abandoned = True
        self._powered.set()
        super().on_unmount()

    def action_stop(self) -> None:
        """Enter: stop (a pending power-cycle prompt is abandoned) and compute."""
        self._abandoned = True
        self._powered.set()
        super().action_stop()

    @work(thread=True, exclusive=True, group="fit")
    def _fit(self) -> None:
        try:
            reduced = []
            for k, rec in enumerate(self.records):
                t = (rec["t_us"].astype(np.float64) - float(rec["t_us"][0])) * 1e-6
                reduced.append(reduce_record(f"turn-on {k + 1}", t, rec["acc"].astype(float),
                                             rec["gyro"].astype(float)))
            acc, gyro = turn_on_repeatability(reduced)
            keys = repeatability_keys(acc, gyro, [r.source for r in reduced])
            out = self.station.config.out
            held = ParamsFile.load(out).other.get(self.SECTION) if out is not None and out.exists() else None
            section = merged(held, keys)
        except StationError as exc:
            self.post_message(LinkFailed(exc))
            return
        self.post_message(Snapshot({"fit": keys, "section": section}))

    def show_fit(self, fit: dict[str, Any]) -> None:
        """The repeatability of both triads, as the datasheet shows it."""
        self._draw_means()
        text = Text(format_table(datasheet_rows({"characterisation": fit})))
        if self.recording.path is not None:
            text.append(f"\nrecording in {self.recording.path}")
        self.query_one("#side", Static).update(text)

