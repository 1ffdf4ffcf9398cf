"""A factory script on the Python API: two units through one plan, their records and history.

The first unit sits on a motorized turntable; the second on a manual fixture that the script
drives (here it tells the person at the line what to do; a PLC call would go in its place).
Both are simulated here (a simulated table, and a simulated hand that follows the script's
instructions); on the line, give the real ports instead of ``simulate=``.

    python examples/factory_script.py [PLAN.yaml] [--db URL]

Exit status: the worst unit's exit code, as ``imu-station run-many`` gives it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from station.acquisition.sequences import RotationStep, Step
from station.factory.api import FactoryStation, ScriptedOperator, SimulatedUnit
from station.factory.many import worst_exit_code


def tell_operator(step: Step, index: int, total: int) -> None:
    what = f"put the unit with {step.label} up" if not isinstance(step, RotationStep) \
        else f"put the unit with {step.start_pose} up, ready to turn it"
    print(f"  fixture {index + 1}/{total}: {what}", file=sys.stderr)


def show(event: dict) -> None:
    """Progress events of the runs (phase, step, step_done, outcome), as a line's display would show."""
    if event["event"] in ("phase", "outcome"):
        print(f"  {event['serial']}: {event['event']} {event.get('phase') or event.get('outcome')}",
              file=sys.stderr)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("plan", nargs="?", default=str(Path(__file__).with_name("plan.yaml")))
    parser.add_argument("--db", default="factory-example.sqlite", help="record database (SQLite path or URL)")
    args = parser.parse_args()

    codes = []
    with FactoryStation(args.plan, db=args.db, station="example-line", on_event=show) as line:
        # On the line: line.run("A1234", port="/dev/ttyUSB0", table_port="/dev/ttyUSB1")
        record = line.run("EX-0001", simulate=SimulatedUnit(seed=1))
        print(f"{record.serial}: {record.outcome} (exit {record.exit_code}), files in {record.files_dir}")
        codes.append(record.exit_code)

        # A manual fixture: the script is told each step and moves the unit (or asks a person to).
        fixture = ScriptedOperator(on_place=tell_operator,
                                   on_rotate=lambda step: print(f"  turn now: {step.label}", file=sys.stderr))
        record = line.run("EX-0002", operator=fixture, simulate=SimulatedUnit(seed=2))
        print(f"{record.serial}: {record.outcome} (exit {record.exit_code}), "
              f"{sum(1 for e in fixture.transcript if e.event == 'place')} placements asked")
        codes.append(record.exit_code)

        for serial in ("EX-0001", "EX-0002"):
            for past in line.history(serial):
                bias = past.measurements().get("accel.bias.z")
                shown = f", accel.bias.z = {bias.value:.4g} {bias.unit}" if bias else ""
                print(f"history {serial}: {past.start} {past.outcome}{shown}")
    return worst_exit_code(codes)


if __name__ == "__main__":
    sys.exit(main())
