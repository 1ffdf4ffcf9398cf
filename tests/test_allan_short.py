"""``imu-station allan`` refuses a record too short for the terms asked for, with the length it needs
(exit 4), keeps what it shows with --force, and names the axis of every printed term."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import yaml

from mocks.rig import Static, simulate
from mocks.truth import NoiseSpec, SensorTruth, UnitTruth
from station import cli
from station.acquisition.capture_csv import write_csv
from station.engines.allan.deviation import allan_curve, cluster_sizes
from station.engines.allan.fit import K_CROSSING_FRACTION, identify_noise, missing_terms

GYRO = NoiseSpec(N=[3e-4, 4e-4, 5e-4], K=[2e-5, 2e-5, 2e-5])
ACCEL = NoiseSpec(N=[2e-3, 2e-3, 3e-3], K=[3e-4, 3e-4, 3e-4])


@pytest.fixture(scope="module")
def short_record():
    truth = UnitTruth(accel=SensorTruth(noise=ACCEL), gyro=SensorTruth(noise=GYRO), serial="SIM-SHORT")
    return simulate(truth, [Static("+z", 60.0)], rate_hz=100.0, seed=21)


@pytest.fixture(scope="module")
def short_csv(short_record, tmp_path_factory):
    path = tmp_path_factory.mktemp("short") / "short.csv"
    write_csv(path, short_record.to_capture())
    return path


def test_a_short_record_is_refused_with_the_length_it_needs(short_csv, tmp_path, capsys) -> None:
    params, curve = tmp_path / "unit.yaml", tmp_path / "curve.csv"
    code = cli.main(["allan", str(short_csv), "-o", str(params), "--curve", str(curve)])
    out, err = capsys.readouterr()
    assert code == 4 and out == "" and "Traceback" not in err
    assert "the record (60 s) is too short for the terms asked for (N,K)" in err
    assert "K (rate random walk) is not resolved on gx, gy, gz, ax, ay, az" in err
    needed = re.search(r"at least ([\d.]+) min", err)
    assert needed and float(needed.group(1)) > 1.0, err
    assert "--force" in err
    assert not params.exists() and not curve.exists()  # nothing taken


def test_force_keeps_what_it_shows_and_fewer_terms_pass(short_csv, tmp_path, capsys) -> None:
    params = tmp_path / "unit.yaml"
    assert cli.main(["allan", str(short_csv), "-o", str(params), "--force"]) == 0
    noise = yaml.safe_load(params.read_text())["noise"]
    assert noise["gyro"]["K"] is None and all(v > 0 for v in noise["gyro"]["N"])
    capsys.readouterr()
    assert cli.main(["allan", str(short_csv), "--terms", "N"]) == 0
    with pytest.raises(SystemExit) as usage:
        cli.main(["allan", str(short_csv), "--terms", "N,X"])
    assert usage.value.code == 4
    assert "give terms among Q,N,B,K,R" in capsys.readouterr().err


def test_default_needs_a_term_on_one_axis_of_each_sensor_terms_on_every_axis(tmp_path, capsys) -> None:
    # 20 min: K shows on every axis but gx, where a spurious correlated bias hides it
    truth = UnitTruth(accel=SensorTruth(noise=ACCEL), gyro=SensorTruth(noise=GYRO), serial="SIM-ALLAN")
    path = tmp_path / "still.csv"
    write_csv(path, simulate(truth, [Static("+z", 1200.0)], rate_hz=100.0, seed=21).to_capture())
    assert cli.main(["allan", str(path)]) == 0
    assert "K of gx: hidden by the correlated (Gauss-Markov) bias" in capsys.readouterr().out
    assert cli.main(["allan", str(path), "--terms", "N,K"]) == 4
    err = capsys.readouterr().err
    assert "K (rate random walk) is not resolved on gx (gx: hidden by the correlated" in err
    assert "it needs a longer record (this one shows no sign of it)" in err


def test_every_printed_term_names_its_axis(short_csv, capsys) -> None:
    assert cli.main(["allan", str(short_csv), "--force"]) == 0
    out = capsys.readouterr().out
    term_lines = [line for line in out.splitlines() if re.match(r"  [QNBKR] [^:]*\]: ", line)]
    assert len(term_lines) == 10
    for line in term_lines:
        axes = ("gx", "gy", "gz") if "rad" in line.split("]")[0] else ("ax", "ay", "az")
        cells = line.split(": ", 1)[1].split(" | ")
        assert [c.split()[0] for c in cells] == list(axes), line
    reasons = [line for line in out.splitlines() if line.startswith("  K of ")]
    assert reasons and all(re.match(r"  K of ([ga][xyz](, )?)+: ", line) for line in reasons)


def test_the_length_asked_for_is_a_lower_bound_of_the_true_one(short_record) -> None:
    phase = np.cumsum(np.column_stack([short_record.gyro, short_record.acc]), axis=0).T / 100.0
    axes = ("gx", "gy", "gz", "ax", "ay", "az")
    curve = allan_curve(phase, 100.0, axes, cluster_sizes(phase.shape[1]))
    _, noise = identify_noise(curve, phase)
    missing = {m.axis: m for m in missing_terms(noise, ("N", "K"), curve.duration_s)}
    assert set(missing) == set(axes)
    truth_n = [*GYRO.N, *ACCEL.N]
    truth_k = [*GYRO.K, *ACCEL.K]
    for j, axis in enumerate(axes):
        true_needed = K_CROSSING_FRACTION * math.sqrt(3.0) * truth_n[j] / truth_k[j]
        needed = missing[axis].needed_s
        assert needed is None or curve.duration_s < needed <= true_needed * 1.5, (axis, needed, true_needed)
    assert any(m.needed_s is not None for m in missing.values())
