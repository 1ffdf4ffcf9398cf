"""Characterisation: turn-on repeatability, gyro scale nonlinearity and asymmetry, g-sensitivity, the
datasheet; recovery of the simulated unit's truth within stated tolerances, each definition against a
direct computation, bad input refused naming the file, and the restart path end to end over a pty."""

from __future__ import annotations

import builtins
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import stats
from scipy.signal import lfilter

from mocks.device import SimDevice
from mocks.pty_server import PtyServer
from mocks.rig import ConstantRate, Static, sequence_segments, simulate
from mocks.truth import NoiseSpec, UnitTruth
from mocks.turntable_sim import TurntableSim
from protocols import native
from station import cli
from station.acquisition.capture import read_capture
from station.acquisition.capture_csv import write_csv
from station.engines.calibration.turntable import TurntableCapture, calibrate_turntable
from station.engines.calibration.turntable_gsens import fit_g_sensitivity
from station.engines.characterisation.scale import rate_steps, scale_linearity
from station.engines.characterisation.turn_on import (
    allan_points,
    mean_noise,
    reduce_record,
    repeatability,
    turn_on_repeatability,
)
from station.errors import EngineInputError
from station.report.datasheet import datasheet_rows, format_table
from tests.export_params import make_params

G = 9.80665
DEG = np.pi / 180
SEED = 21
RATES_DPS = (20.0, 100.0, 250.0, 500.0)


def unit(seed: int = SEED) -> UnitTruth:
    """A MEMS unit with a quadratic and an asymmetric gyro scale term on every axis."""
    truth = UnitTruth.random(seed)
    truth.gyro.scale_quadratic[:] = [2e-4, -1e-4, 3e-4]       # per rad/s
    truth.gyro.scale_asymmetry[:] = [300e-6, -200e-6, 500e-6]
    return truth


def still_records(truth: UnitTruth, n: int, seconds: float = 10.0, rate_hz: float = 100.0,
                  pose: str = "+z") -> list:
    return [simulate(truth.turned_on(k, SEED), [Static(pose, seconds)], rate_hz=rate_hz, seed=1000 + k)
            for k in range(n)]


def reduced(records: list, prefix: str = "still") -> list:
    return [reduce_record(f"{prefix}{k}.csv", r.t, r.acc, r.gyro, "+z") for k, r in enumerate(records)]


# ---- turn-on repeatability ------------------------------------------------------------------------


def test_turn_on_repeatability_recovers_the_spread_of_the_drawn_biases() -> None:
    truth = unit()
    n = 30
    acc, gyro = turn_on_repeatability(reduced(still_records(truth, n)))
    drawn_g = np.array([truth.turned_on(k, SEED).gyro.bias for k in range(n)]).std(axis=0, ddof=1)
    drawn_a = np.array([truth.turned_on(k, SEED).accel.bias for k in range(n)]).std(axis=0, ddof=1)
    # the drawn biases' own spread, to the in-run noise left in each mean (bias instability, 5 %)
    np.testing.assert_allclose(gyro.sigma, drawn_g, rtol=0.05)
    np.testing.assert_allclose(acc.sigma, drawn_a, rtol=0.05)
    # the 68 % interval holds the estimate; the truth's sigma is within the sampling error of 30 draws
    # (relative 1-sigma 1 / sqrt(2 (n - 1)) = 13 %; 45 % is 3.4 sigma)
    for rep, sigma in ((gyro, truth.gyro.turn_on_sigma), (acc, truth.accel.turn_on_sigma)):
        assert np.all(rep.interval[:, 0] <= rep.sigma) and np.all(rep.sigma <= rep.interval[:, 1])
        np.testing.assert_allclose(rep.sigma, sigma, rtol=0.45)
    assert acc.turn_ons == gyro.turn_ons == n


def test_in_run_noise_of_the_means_is_removed() -> None:
    # no turn-on spread, only white noise: the means still scatter, the repeatability is ~0
    truth = UnitTruth.ideal().with_noise(accel=NoiseSpec(N=2e-3), gyro=NoiseSpec(N=1e-3))
    acc, gyro = turn_on_repeatability(reduced(still_records(truth, 12, seconds=5.0)))
    assert np.all(gyro.spread > 0)
    assert np.all(gyro.sigma <= 0.5 * gyro.spread)
    assert np.all(gyro.interval[:, 0] == 0.0)
    # the in-run noise of a mean is N / sqrt(T) for white noise (T = 5 s; 12 records: within 25 %)
    np.testing.assert_allclose(gyro.in_run, 1e-3 / np.sqrt(5.0), rtol=0.25)
    np.testing.assert_allclose(acc.in_run, 2e-3 / np.sqrt(5.0), rtol=0.25)


def test_mean_noise_agrees_with_the_scatter_of_independent_means() -> None:
    rng = np.random.default_rng(3)
    n = 2000  # 20 s at 100 Hz
    white = rng.standard_normal((300, n, 1))
    a = np.exp(-0.01 / 20.0)  # a Gauss-Markov drift of 20 s correlation time on white noise
    drift = lfilter([1.0], [1.0, -a], rng.standard_normal((300, n, 1)) * np.sqrt(1 - a * a) * 0.2, axis=1)
    # five records pooled at a time, as five turn-ons would be: white noise within 20 %, a drift as
    # long as the records (the hardest case: it is barely told from a turn-on change) within 50 %
    for records, tolerance in ((white, 0.2), (drift + 0.5 * white, 0.5)):
        predicted = [mean_noise([allan_points(r, 100.0) for r in records[i : i + 5]])
                     for i in range(0, 60, 5)]
        rms = np.sqrt(np.mean(np.square(predicted)))
        assert rms == pytest.approx(records.mean(axis=1).std(), rel=tolerance)


def test_repeatability_follows_its_definition() -> None:
    rng = np.random.default_rng(5)
    means = rng.normal(0.0, 1.0, (7, 3))
    noise = np.full((7, 3), 0.3)
    rep = repeatability(means, noise, level=0.9)
    s2 = means.var(axis=0, ddof=1)
    np.testing.assert_allclose(rep.sigma, np.sqrt(s2 - 0.09))
    lo = 6 * s2 / stats.chi2.ppf(0.95, 6) - 0.09
    hi = 6 * s2 / stats.chi2.ppf(0.05, 6) - 0.09
    np.testing.assert_allclose(rep.interval, np.sqrt(np.maximum(np.column_stack([lo, hi]), 0)), rtol=1e-12)


def test_bad_turn_on_input_is_refused_naming_the_file() -> None:
    truth = unit()
    records = still_records(truth, 3, seconds=2.0)
    with pytest.raises(EngineInputError, match=r"2 turn-on record\(s\) \(still0.csv, still1.csv\).*least 3"):
        turn_on_repeatability(reduced(records[:2]))
    other = simulate(truth, [Static("-x", 2.0)], rate_hz=100)
    bad = reduced(records[:2]) + [reduce_record("tilted.csv", other.t, other.acc, other.gyro)]
    with pytest.raises(EngineInputError, match="tilted.csv: gravity is .* deg away from .* still0.csv"):
        turn_on_repeatability(bad)
    fast = simulate(truth, [Static("+z", 2.0)], rate_hz=200)
    bad = reduced(records[:2]) + [reduce_record("fast.csv", fast.t, fast.acc, fast.gyro, "+z")]
    with pytest.raises(EngineInputError, match="fast.csv: sampled at 200 Hz, still0.csv at 100 Hz"):
        turn_on_repeatability(bad)
    short = records[0]
    with pytest.raises(EngineInputError, match="short.csv: 30 samples"):
        reduce_record("short.csv", short.t[:30], short.acc[:30], short.gyro[:30])


# ---- scale-factor nonlinearity and asymmetry ----------------------------------------------------------


def rate_segments(rates=RATES_DPS, hold_s: float = 2.0, settle_s: float = 0.5) -> list:
    segments = []
    for axis in "xyz":
        for r in rates:
            segments += [ConstantRate("+" + axis, r, hold_s, settle_s=settle_s),
                         ConstantRate("-" + axis, r, hold_s, settle_s=settle_s)]
    return segments


def by_definition(w: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Nonlinearity, asymmetry (ppm) and slope by the spec's words, with numpy.polyfit."""
    k, c = np.polyfit(w, y, 1)
    nl = np.max(np.abs(y - (k * w + c))) / np.max(np.abs(y)) * 1e6
    kp = np.polyfit(w[w > 0], y[w > 0], 1)[0]
    kn = np.polyfit(w[w < 0], y[w < 0], 1)[0]
    return nl, (kp - kn) / ((kp + kn) / 2) * 1e6, k


@pytest.fixture(scope="module")
def rates_capture():
    truth = unit()
    rec = simulate(truth, rate_segments(), rate_hz=200, seed=9)
    return truth, rec


def test_scale_figures_follow_the_definitions_on_the_step_means(rates_capture) -> None:
    _, rec = rates_capture
    steps = rate_steps(rec.t, rec.gyro, rec.step, "rates.csv")
    assert len(steps) == 24
    axes = scale_linearity(steps, "rates.csv")
    for i, result in enumerate(axes):
        mine = [s for s in steps if s.axis == i]
        w, y = np.array([s.rate for s in mine]), np.array([s.mean for s in mine])
        nl, asym, k = by_definition(w, y)
        assert result.nonlinearity_ppm == pytest.approx(nl, rel=1e-9)
        assert result.asymmetry_ppm == pytest.approx(asym, rel=1e-9)
        assert result.scale_error_ppm == pytest.approx((k - 1) * 1e6, rel=1e-9)


def test_scale_figures_recover_the_truths_nonlinearity_and_asymmetry(rates_capture) -> None:
    truth, rec = rates_capture
    axes = scale_linearity(rate_steps(rec.t, rec.gyro, rec.step, "rates.csv"), "rates.csv")
    for i, result in enumerate(axes):
        # the truth: the definitions applied to the noise-free output at the same rates
        w = np.radians(np.concatenate([RATES_DPS, -np.array(RATES_DPS)]))
        true_rate = np.zeros((len(w), 3))
        true_rate[:, i] = w
        exact = dataclasses.replace(truth.gyro, resolution=None)  # the noise dithers the 16-bit output
        out = exact.measure(true_rate, np.full(len(w), 25.0), np.zeros(len(w)))[:, i]
        nl, asym, k = by_definition(w, out - truth.gyro.bias[i])
        # tolerances: 3 sigma of the figures' own uncertainty plus the 16-bit output quantum's share
        assert abs(result.nonlinearity_ppm - nl) < 3 * result.nonlinearity_sd_ppm + 40
        assert abs(result.asymmetry_ppm - asym) < 3 * result.asymmetry_sd_ppm + 40
        assert abs(result.scale_error_ppm - (k - 1) * 1e6) < 3 * result.scale_error_sd_ppm + 40
        assert result.nonlinearity_ppm > 300 and abs(result.asymmetry_ppm) > 300  # the terms show


def test_rate_steps_too_short_or_unsettled_or_one_way_are_refused() -> None:
    truth = unit()
    rec = simulate(truth, [ConstantRate("+z", 90.0, 0.05)], rate_hz=200)
    with pytest.raises(EngineInputError, match=r"rates.csv: step rate\+z:90 at t = .* 10 steady samples"):
        rate_steps(rec.t, rec.gyro, rec.step, "rates.csv")
    rec = simulate(truth, [ConstantRate("+z", 200.0, 1.0, settle_s=0.0, ramp_s=1.0)], rate_hz=200)
    labels = np.array([str(s) for s in rec.step], dtype=object)
    spin_up = (rec.t > 2.2) & (rec.t < 3.0)  # the ramp, after the move to +z up, labelled as if steady
    labels[spin_up] = "rate+z:200"
    labels[(rec.t >= 3.0)] = ""
    with pytest.raises(EngineInputError, match=r"rate\+z:200 .* the table had not settled"):
        rate_steps(rec.t, rec.gyro, labels, "rates.csv")
    rec = simulate(truth, [ConstantRate("+z", r, 1.0) for r in RATES_DPS], rate_hz=200)
    with pytest.raises(EngineInputError, match="axis z has rate steps at .*both ways"):
        scale_linearity(rate_steps(rec.t, rec.gyro, rec.step, "rates.csv"), "rates.csv")


# ---- gyro g-sensitivity ---------------------------------------------------------------------------


G_TRUE = np.array([[0.05, -0.02, 0.01], [0.03, 0.04, -0.06], [-0.01, 0.02, 0.08]]) * DEG / G  # deg/s/g


@pytest.mark.parametrize("sequence", ["twelve-position", "six-position"])
def test_g_sensitivity_is_recovered_from_the_static_poses(sequence: str) -> None:
    truth = UnitTruth.random(4)
    truth.g_sensitivity = G_TRUE
    rec = simulate(truth, sequence_segments(sequence, hold_s=4.0), rate_hz=100, seed=2)
    report = calibrate_turntable(TurntableCapture(rec.t, rec.acc, rec.gyro, rec.step))
    estimate = np.asarray(report.gyro.extra["g_sensitivity"])
    sd = np.asarray(report.gyro.stddev["g_sensitivity"])
    assert np.all(np.abs(estimate - G_TRUE) < 4 * sd + 1e-5)
    # tolerance in datasheet units: 0.01 deg/s/g on every term
    assert np.max(np.abs(estimate - G_TRUE)) * G / DEG < 0.01
    assert not [w for w in report.warnings if "g-sensitivity" in w]
    # each turn's g-sensitivity (g along its vertical axis) is taken out of its integral
    assert all(abs(p["angle_error_deg"]) < 0.05 for p in report.poses if p["kind"] == "rotation")
    np.testing.assert_allclose(report.gyro.matrix, truth.gyro.matrix, atol=2e-3)


def test_poses_that_never_turn_an_axis_leave_its_column_undetermined() -> None:
    # (a pose set that determines the accelerometer determines G too: the designs are the same, eq. 1)
    up = np.array([[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1], [1, 0, 1], [0, 0, -1]], float)
    force = G * up / np.linalg.norm(up, axis=1, keepdims=True)
    labels = ["+x", "-x", "+z", "-z", "+z+x", "-z"]
    result = fit_g_sensitivity(force @ G_TRUE.T, force, np.full((6, 3), 1e-12), labels)
    assert result.matrix is None and result.determined.tolist() == [True, False, True]
    (warning,) = result.warnings
    assert "do not determine the column(s) y of G" in warning
    force = np.vstack([force, [[0, G, 0], [0, -G, 0]]])  # with +y and -y the column is there
    full = fit_g_sensitivity(force @ G_TRUE.T, force, np.full((8, 3), 1e-12), labels + ["+y", "-y"])
    np.testing.assert_allclose(full.matrix, G_TRUE, atol=1e-12)


# ---- the command and the datasheet ------------------------------------------------------------------


@pytest.fixture(scope="module")
def files(tmp_path_factory, rates_capture) -> tuple[UnitTruth, list[Path], Path]:
    folder = tmp_path_factory.mktemp("characterise")
    truth, rec = rates_capture
    stills = []
    for k, r in enumerate(still_records(truth, 5, seconds=5.0)):
        stills.append(folder / f"still{k}.csv")
        write_csv(stills[-1], r.to_capture())
    rates = folder / "rates.csv"
    write_csv(rates, rec.to_capture())
    return truth, stills, rates


def test_characterise_writes_the_section_and_keeps_earlier_keys(files, tmp_path, capsys) -> None:
    truth, stills, rates = files
    params = tmp_path / "unit.yaml"
    assert cli.main(["characterise", *map(str, stills), "-o", str(params)]) == 0
    assert "gyro turn-on bias repeatability" in capsys.readouterr().out
    assert cli.main(["characterise", str(rates), "-o", str(params), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    section = yaml.safe_load(params.read_text())["characterisation"]
    assert section["turn_ons"] == 5 and len(section["gyro_bias_repeatability"]) == 3  # kept
    assert section["gyro_scale_nonlinearity_ppm"] == result["characterisation"]["gyro_scale_nonlinearity_ppm"]
    assert section["rate_records"] == [str(rates)] and len(section["turn_on_records"]) == 5


def test_characterise_refuses_two_turn_ons_and_mixed_poses_naming_the_file(files, tmp_path, capsys) -> None:
    truth, stills, _ = files
    assert cli.main(["characterise", str(stills[0]), str(stills[1])]) == 4
    assert "2 turn-on record(s)" in capsys.readouterr().err
    six = tmp_path / "six.csv"
    rec = simulate(truth, sequence_segments("six-position", rotations=False, hold_s=1.0))
    write_csv(six, rec.to_capture())
    assert cli.main(["characterise", *map(str, stills), str(six)]) == 4
    assert f"{six}: holds several poses" in capsys.readouterr().err


def test_datasheet_in_datasheet_units(tmp_path, capsys) -> None:
    params = make_params(seed=3, g_sensitivity=True)
    params.noise = {"gyro": {"N": [1e-4] * 3, "B": [2e-5] * 3, "stddev": {"N": [1e-6] * 3, "B": [1e-6] * 3}},
                    "accel": {"N": [1e-3] * 3, "B": [4e-4] * 3, "stddev": {"N": [1e-5] * 3, "B": [2e-5] * 3}}}
    params.other["characterisation"] = {
        "turn_ons": 5, "gyro_bias_repeatability": [1e-3, 2e-3, None], "repeatability_level": 0.683,
        "gyro_bias_repeatability_interval": [[5e-4, 2e-3], [1e-3, 4e-3], None]}
    path = tmp_path / "unit.yaml"
    params.save(path)
    rows = {r.figure: r for r in datasheet_rows(yaml.safe_load(path.read_text()))}
    assert rows["angle random walk"].values[0] == pytest.approx(1e-4 / DEG * 60)          # deg/sqrt(h)
    assert rows["gyro in-run bias stability"].values[0] == pytest.approx(2e-5 / DEG * 3600)  # deg/h
    assert rows["accel in-run bias stability"].values[0] == pytest.approx(4e-4 / G * 1e6)   # ug
    assert rows["velocity random walk"].values[0] == pytest.approx(1e-3 * 60)              # m/s/sqrt(h)
    assert rows["gyro turn-on bias repeatability"].values[2] is None
    g_sens = np.asarray(yaml.safe_load(path.read_text())["gyro"]["g_sensitivity"])
    assert rows["gyro g-sensitivity, force along y"].values == pytest.approx(g_sens[:, 1] / DEG * G)
    scale = yaml.safe_load(path.read_text())["gyro"]["scale"]
    assert rows["gyro scale-factor error"].values == pytest.approx([(k - 1) * 1e6 for k in scale])
    assert rows["gyro bias temperature sensitivity"].unit == "deg/s/degC"
    assert "accel misalignment" in rows
    assert cli.main(["characterise", "--datasheet", "--params", str(path)]) == 0
    out = capsys.readouterr().out
    assert "angle random walk" in out and "[0.0286, 0.115]" in out  # the interval of 1e-3 rad/s in deg/s
    assert cli.main(["characterise", "--datasheet", "--params", str(path), "--json"]) == 0
    table = json.loads(capsys.readouterr().out)["datasheet"]["rows"]
    assert {r["figure"] for r in table} == set(rows)
    assert format_table(list(rows.values())).count("\n") == len(rows)


# ---- the restart path over a real pty ---------------------------------------------------------------


def test_turn_ons_recorded_through_restart_over_a_pty(tmp_path, capsys) -> None:
    truth = unit()
    device = SimDevice(truth, seed=SEED, rate_hz=100)
    params = tmp_path / "unit.yaml"
    keep = tmp_path / "turn-ons"
    with PtyServer(device, speed=20.0) as server:
        code = cli.main(["characterise", "--port", server.port_path, "--turn-ons", "4", "--still", "3",
                         "--keep", str(keep), "-o", str(params)])
    assert code == 0, capsys.readouterr().err
    assert device.restarts == 3 and device.commands["RESTART"] == 3
    assert sorted(p.name for p in keep.iterdir()) == [f"turn-on-0{k}.csv" for k in range(1, 5)]
    section = yaml.safe_load(params.read_text())["characterisation"]
    assert section["turn_ons"] == 4
    drawn = np.array([truth.turned_on(k, SEED).gyro.bias for k in range(4)]).std(axis=0, ddof=1)
    np.testing.assert_allclose(section["gyro_bias_repeatability"], drawn, rtol=0.25, atol=2e-4)


def test_a_unit_that_cannot_restart_is_power_cycled_by_the_operator(tmp_path, capsys, monkeypatch) -> None:
    device = SimDevice(unit(), seed=SEED, rate_hz=100, restartable=False)
    asked = []

    def operator_power_cycles(*_: object) -> str:
        asked.append(True)
        device.restartable = True          # the operator's switch: the unit powers up again
        device.feed(native.encode_frame(native.RESTART))
        device.restartable = False
        return ""

    monkeypatch.setattr(builtins, "input", operator_power_cycles)
    monkeypatch.setattr(sys.stdin, "isatty", lambda: True, raising=False)
    with PtyServer(device, speed=20.0) as server:
        code = cli.main(["characterise", "--port", server.port_path, "--turn-ons", "3", "--still", "2"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert len(asked) == 2 and device.restarts == 2
    assert "cannot restart itself. Switch it off" in err


def test_a_unit_that_cannot_restart_without_a_terminal_is_an_error(tmp_path, capsys, monkeypatch) -> None:
    monkeypatch.setattr(sys.stdin, "isatty", lambda: False, raising=False)
    device = SimDevice(unit(), seed=SEED, rate_hz=100, restartable=False)
    with PtyServer(device, speed=20.0) as server:
        code = cli.main(["characterise", "--port", server.port_path, "--turn-ons", "3", "--still", "1"])
    assert code == 4
    assert "cannot restart itself (it answered RESTART with status 1" in capsys.readouterr().err


def test_rate_steps_recorded_on_the_simulated_rate_table(tmp_path, capsys) -> None:
    truth = unit()
    truth.gyro.noise.N[:] = 0.003 * DEG  # quieter than the MEMS grade: short steps at x20 speed
    device = SimDevice(truth, seed=SEED, rate_hz=200)
    params = tmp_path / "unit.yaml"
    with PtyServer(device, speed=20.0) as server, TurntableSim(server.device, rate_settle_s=0.5) as table:
        code = cli.main(["characterise", "--port", server.port_path, "--table", table.port_path,
                         "--rates", "50,200,400", "--axes", "z", "--hold", "2", "--keep", str(tmp_path),
                         "-o", str(params)])
        assert code == 0, capsys.readouterr().err
        spins = [c for c in table.commands if c.startswith("SPIN")]
    assert spins == ["SPIN +z 50 2", "SPIN +z 200 2", "SPIN +z 400 2", "SPIN +z -50 2", "SPIN +z -200 2",
                     "SPIN +z -400 2"]
    capture = read_capture(tmp_path / "rates.csv")
    steps = {label: sl for label, sl in capture.segments()}
    assert set(steps) == {"rate+z:50", "rate+z:200", "rate+z:400", "rate-z:50", "rate-z:200", "rate-z:400"}
    for label, sl in steps.items():  # labelled only while steady: 2 s each, at the asked rate
        assert (sl.stop - sl.start) == pytest.approx(400, abs=4)
        rate = float(label.split(":")[1]) * (1 if "+" in label else -1)
        steady = (capture.gyro[sl, 2] - truth.gyro.bias[2]) / truth.gyro.scale[2]
        np.testing.assert_allclose(steady, np.radians(rate), rtol=0.01)
    section = yaml.safe_load(params.read_text())["characterisation"]
    w = np.radians(np.array([50.0, 200.0, 400.0, -50.0, -200.0, -400.0]))
    exact = dataclasses.replace(truth.gyro, resolution=None)
    out = exact.measure(np.column_stack([0 * w, 0 * w, w]), np.full(6, 25.0), np.zeros(6))[:, 2]
    nl, asym, _ = by_definition(w, out)
    assert section["gyro_scale_nonlinearity_ppm"][:2] == [None, None]
    for key, truth_value in (("gyro_scale_nonlinearity", nl), ("gyro_scale_asymmetry", asym)):
        assert abs(section[f"{key}_ppm"][2] - truth_value) < 3 * section[f"{key}_sd_ppm"][2] + 40


def test_options_that_do_not_go_together_are_refused(capsys) -> None:
    assert cli.main(["characterise", "--port", "/dev/null", "--table", "/dev/null"]) == 4
    assert "rate steps need both --table TABLE and --rates" in capsys.readouterr().err
    assert cli.main(["characterise", "--port", "/dev/null", "--turn-ons", "3"]) == 4
    assert "need both --turn-ons N (3 or more) and --still S" in capsys.readouterr().err
    assert cli.main(["characterise", "--turn-ons", "3", "--still", "5"]) == 4
    assert "go with --port" in capsys.readouterr().err
    assert cli.main(["characterise", "--datasheet"]) == 4
    assert "--datasheet reads a parameter file" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["characterise", "--port", "/dev/null", "--table", "/dev/null", "--rates", "10,20"])
    assert "three or more distinct rates" in capsys.readouterr().err


def test_a_unit_whose_protocol_has_no_restart_is_power_cycled_by_the_operator(monkeypatch, capsys) -> None:
    import mocks.encoders_extra  # noqa: F401  (registers the Xsens encoder)

    device = SimDevice(unit(), seed=SEED, rate_hz=100, encoder="xsens")
    cycles = []

    def operator_power_cycles(*_: object) -> str:
        cycles.append(True)
        device.feed(native.encode_frame(native.RESTART))  # the switch: the unit powers up again
        return ""

    monkeypatch.setattr(builtins, "input", operator_power_cycles)
    monkeypatch.setattr(sys.stdin, "isatty", lambda: True, raising=False)
    with PtyServer(device, speed=20.0) as server:
        code = cli.main(["characterise", "--port", server.port_path, "--protocol", "xsens", "--turn-ons", "3",
                         "--still", "2"])
    assert code == 0, capsys.readouterr().err
    assert len(cycles) == 2 and device.restarts == 2
