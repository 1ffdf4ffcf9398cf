"""The Python API for factory scripts: run units against a plan, read their records.

::

    from station.factory.api import FactoryStation

    with FactoryStation("plan.yaml", db="line.sqlite", station="line-a-3") as line:
        record = line.run("A1234", port="/dev/ttyUSB0", table_port="/dev/ttyUSB1")
        print(record.outcome, record.exit_code, record.measurements()["gyro.bias.z"].value)
        history = line.history("A1234")

A manual fixture (no motorized table) is driven by the script through an operator: a
:class:`~station.acquisition.operator.ScriptedOperator` whose ``on_place`` / ``on_rotate``
move the fixture or tell the person at the line, and the station waits, from the unit's own
samples, until the unit is in pose and still::

    fixture = ScriptedOperator(on_place=lambda step, i, n: plc.move_to(step.label),
                               on_rotate=lambda step: plc.turn(step.label))
    record = line.run("A1234", port="/dev/ttyUSB0", operator=fixture)

``simulate=SimulatedUnit(seed=3)`` runs a simulated unit on a simulated table instead, through
pseudo-terminals (see ``examples/factory_script.py``). Runs are recorded exactly as
``imu-station run`` records them.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path
from types import TracebackType

from station.acquisition.operator import Operator, ScriptedOperator
from station.factory.plan import Plan, load_plan
from station.factory.records import RecordStore, RunRecord
from station.factory.run import EventSink, RunRequest
from station.factory.simrig import SimulatedUnit
from station.factory.unit import run_unit

__all__ = ["FactoryStation", "RunRecord", "ScriptedOperator", "SimulatedUnit"]


class FactoryStation:
    """One station of a line: a plan, a record database and where files are kept.

    Parameters
    ----------
    plan : the plan file (or a loaded :class:`~station.factory.plan.Plan`).
    db : SQLite path or ``postgresql://...`` (default ``$IMU_STATION_DB`` or ``imu-station-records.sqlite``).
    station : this station's id (default ``$IMU_STATION_ID`` or the host name).
    files : where captures, parameter files and exports are kept (default beside a SQLite db).
    on_event : called with each progress event (phase, step, step_done, outcome) as a dict.
    """

    def __init__(self, plan: str | Path | Plan, db: str | None = None, station: str | None = None,
                 files: str | Path | None = None, on_event: EventSink | None = None):
        self.plan = plan if isinstance(plan, Plan) else load_plan(plan)
        self.db = db or os.environ.get("IMU_STATION_DB") or "imu-station-records.sqlite"
        self.station = station or os.environ.get("IMU_STATION_ID") or socket.gethostname()
        if files is None:
            is_sqlite = "://" not in self.db or self.db.startswith("sqlite:///")
            db_path = Path(self.db.removeprefix("sqlite:///"))
            files = db_path.with_name(db_path.stem + "-files") if is_sqlite else "imu-station-files"
        self.files = Path(files)
        self.on_event = on_event
        self.store = RecordStore.open(self.db)

    def run(self, serial: str = "auto", port: str | None = None, table_port: str | None = None,
            operator: Operator | None = None, simulate: SimulatedUnit | None = None) -> RunRecord:
        """Run one unit through the plan and record it; the record's ``exit_code`` is the CLI's."""
        request = RunRequest(plan=self.plan, serial=serial, station=self.station, port=port,
                             table_port=table_port, operator=operator, simulate=simulate,
                             files_root=self.files, on_event=self.on_event)
        return run_unit(request, self.store)

    def history(self, serial: str, since: str | None = None, until: str | None = None) -> list[RunRecord]:
        """Every record of one unit, oldest first."""
        return self.store.query(serial, since, until)

    def close(self) -> None:
        """Close the record store."""
        self.store.close()

    def __enter__(self) -> FactoryStation:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
