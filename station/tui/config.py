"""What the ``tui`` command was asked for."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from station.factory.plan import Plan


@dataclass
class TuiConfig:
    """Options of ``imu-station tui``; ``port`` None and ``simulate`` False: choose on the connect screen."""

    port: str | None = None
    simulate: bool = False
    protocol: str = "native"
    sequence: str = "six-position"
    rotations: bool = True
    out: Path | None = None
    capture: Path | None = None
    export: list[str] = field(default_factory=list)
    export_dir: Path | None = None
    hold_s: float = 5.0
    rotation_rate_dps: float = 90.0
    seed: int = 0
    rate_hz: float = 200.0
    speed: float = 1.0
    allan_minutes: float = 60.0
    plan: Plan | None = None  # whose limits judge the results (None: the built-in ones)
    mag: bool = False  # the simulated unit has a magnetometer
    supply: str | None = None  # the bench supply powering the unit (URL): turn-ons power-cycle through it
    supply_volts: float | None = None
    supply_amps: float | None = None
    supply_max_v: float = 12.0
    supply_max_a: float = 1.0
    supply_off_s: float = 2.0
    table: str | None = None  # a rate table carrying the unit (URL): it places and turns it in the wizard
    table_mount: str = "+z"
    table_max_rate_dps: float | None = None
    table_accel_dps2: float = 100.0

    def capture_path(self) -> Path | None:
        """Where the labelled capture goes: ``--capture``, else beside ``--out``."""
        if self.capture is not None:
            return self.capture
        if self.out is not None:
            return self.out.with_name(self.out.stem + "-capture.csv")
        return None

    def mag_capture_path(self) -> Path | None:
        """Where the magnetometer step's capture goes: beside ``--capture`` (``NAME-mag.csv``), else
        beside ``--out``."""
        if self.capture is not None:
            return self.capture.with_name(self.capture.stem + "-mag" + self.capture.suffix)
        if self.out is not None:
            return self.out.with_name(self.out.stem + "-mag-capture.csv")
        return None
