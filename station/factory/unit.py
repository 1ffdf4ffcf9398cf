"""Run one unit, a plain run or a chamber campaign (``station.factory.campaign``, a run of many steps
that may resume), and keep its record: what ``imu-station run`` and the factory API call."""

from __future__ import annotations

import logging

from station.factory.campaign import CampaignRun
from station.factory.records import RecordStore, RunRecord
from station.factory.run import RunRequest, UnitRun
from station.factory.spool import keep

log = logging.getLogger("imu_station.factory")


def run_unit(request: RunRequest, store: RecordStore | None = None) -> RunRecord:
    """Run one unit and save its record in ``store`` (when given); a record the store does not take
    is kept pending in ``files_root`` (``station.factory.spool``), logged, and the record returned.

    Parameters
    ----------
    request : RunRequest
        The unit, the plan and how to reach them.
    store : RecordStore, optional
        Where the record is saved.

    Returns
    -------
    RunRecord
        The run's record (outcome, exit code, phases, measurements, attachments).
    """
    if request.plan.campaign is not None or request.resume is not None:
        record = CampaignRun(request).execute()
    else:
        record = UnitRun(request).execute()
    if store is not None:
        pending = keep(record, store, request.files_root)
        if pending is not None:
            log.warning("record %s pending in %s: %s", record.run_id, pending.path, pending.reason)
    return record
