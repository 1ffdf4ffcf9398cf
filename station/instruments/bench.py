"""A run's instruments together: opened from the plan, held to its limits, left safe on any way out.

A plan names its instruments and what the station may ask of them::

    instruments:
      chamber: {url: "votsch://10.0.0.5", min_c: -40, max_c: 85, max_gradient: 3}
      table: {url: "acutrol://10.0.0.7:5000", max_rate_dps: 400, max_accel_dps2: 200}
      supply: {url: "scpi://10.0.0.9?channel=1", max_v: 12, max_a: 1}
      on_abort: {chamber: hold, table: stop, supply: keep}

:func:`open_bench` opens each (closing those already open if one cannot be reached), wraps it in
the limits, and leaves every instrument as ``on_abort`` says when the block ends by an exception,
Ctrl-C or SIGTERM (which it turns into the same KeyboardInterrupt while the block runs in the main
thread): a table ``stop`` (or ``home``), a chamber ``hold`` (its setpoint as it is), ``stop``
(standby) or ``setpoint:C``, a supply ``keep`` or ``off``. Making an instrument safe never raises:
what failed is in the notes, so the other instruments are still made safe.
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from types import FrameType

from drivers.instruments import Chamber, Instrument, Supply, Table, Transcript
from station.errors import StationError
from station.instruments.limits import Limits, limited
from station.instruments.open import open_instrument

ON_ABORT = {"chamber": ("hold", "stop", "setpoint:C"), "table": ("stop", "home"), "supply": ("keep", "off")}
"""What ``on_abort`` may say for each kind (``setpoint:C`` with a number, e.g. ``setpoint:23``)."""


@dataclass(frozen=True)
class OnAbort:
    """What each instrument is left doing when a run ends early."""

    chamber: str = "hold"
    table: str = "stop"
    supply: str = "keep"


def check_on_abort(kind: str, action: str) -> str | None:
    """Why ``action`` is not a valid ``on_abort`` for ``kind`` (None when it is)."""
    allowed = ON_ABORT[kind]
    if action in allowed:
        return None
    if kind == "chamber" and action.startswith("setpoint:"):
        try:
            float(action.split(":", 1)[1])
            return None
        except ValueError:
            pass
    return f"on_abort {kind} must be one of {', '.join(allowed)}, not {action!r}"


@dataclass(frozen=True)
class InstrumentPlan:
    """The plan's ``instruments:`` section: URLs, limits, ``on_abort``, and what the run does with
    them: the unit mounted on the table (``mount``), the supply's voltage and current limit (the
    output switched on before the unit is opened), the soak temperature and when it has settled."""

    chamber: str | None = None
    table: str | None = None
    supply: str | None = None
    limits: Limits = Limits()
    on_abort: OnAbort = OnAbort()
    mount: str = "+z"
    supply_v: float | None = None
    supply_a: float | None = None
    soak_c: float | None = None
    settle_rate_c_per_min: float = 0.05
    settle_s: float = 300.0
    settle_timeout_s: float = 3600.0

    def with_urls(self, urls: dict[str, str]) -> InstrumentPlan:
        """The same plan with some instruments' URLs replaced (the simulated ones)."""
        return dataclasses.replace(self, chamber=urls.get("chamber", self.chamber),
                                   table=urls.get("table", self.table),
                                   supply=urls.get("supply", self.supply))

    def urls(self) -> dict[str, str]:
        """Kind -> URL of the instruments named."""
        return {k: u for k, u in (("chamber", self.chamber), ("table", self.table), ("supply", self.supply))
                if u is not None}


@dataclass
class Bench:
    """The open instruments of one run (None where the plan names none) and their transcript."""

    chamber: Chamber | None = None
    table: Table | None = None
    supply: Supply | None = None
    on_abort: OnAbort = OnAbort()
    transcript: Transcript = field(default_factory=Transcript)
    notes: list[str] = field(default_factory=list)

    def instruments(self) -> list[Instrument]:
        """Those open, table first (a turning table is the most urgent to stop)."""
        return [i for i in (self.table, self.chamber, self.supply) if i is not None]

    def identities(self) -> dict[str, dict[str, str]]:
        """Kind -> {url, identity}, for the run record's reference equipment."""
        out = {}
        for instrument in self.instruments():
            try:
                identity = instrument.identify()
            except StationError as exc:
                identity = f"(not answered: {exc})"
            out[instrument.kind] = {"url": instrument.url, "identity": identity}
        return out

    def leave_safe(self) -> list[str]:
        """Put every instrument as ``on_abort`` says; the notes say what was done and what failed."""
        done = []
        for instrument in self.instruments():
            action = getattr(self.on_abort, instrument.kind)
            try:
                if isinstance(instrument, Table):
                    instrument.stop()
                    if action == "home":
                        instrument.home()
                elif isinstance(instrument, Chamber):
                    if action == "stop":
                        instrument.stop()
                    elif action.startswith("setpoint:"):
                        instrument.set_setpoint(float(action.split(":", 1)[1]))
                elif isinstance(instrument, Supply) and action == "off":
                    instrument.set_output(False)
                done.append(f"{instrument.kind} {instrument.url}: {action}")
            except StationError as exc:
                done.append(f"{instrument.kind} {instrument.url}: {action} FAILED: {exc}")
        self.notes += done
        return done

    def close(self) -> None:
        """Close every link (never raises)."""
        for instrument in self.instruments():
            with contextlib.suppress(Exception):
                instrument.close()


def _sigterm(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@contextlib.contextmanager
def open_bench(plan: InstrumentPlan, transcript: Transcript | None = None) -> Iterator[Bench]:
    """Open the plan's instruments for the block; on an exception, Ctrl-C or SIGTERM leave them safe.

    Parameters
    ----------
    plan : InstrumentPlan
        URLs, limits and ``on_abort``.
    transcript : Transcript, optional
        Where every command and reply goes (a new one by default).

    Yields
    ------
    Bench
    """
    bench = Bench(on_abort=plan.on_abort, transcript=transcript if transcript is not None else Transcript())
    try:
        for kind, url in plan.urls().items():
            setattr(bench, kind, limited(open_instrument(url, bench.transcript, kind=kind), plan.limits))
    except BaseException:
        bench.close()
        raise
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _sigterm) if main else None
    try:
        yield bench
    except BaseException:
        bench.leave_safe()
        raise
    finally:
        if main:
            signal.signal(signal.SIGTERM, previous)
        bench.close()
