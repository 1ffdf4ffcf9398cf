"""``calibrate --method mag`` over captures that cannot determine a magnetometer calibration (issue 31).

Each capture is refused with exit 4 and one line that says what to do, or fitted with finite, real
values whose 1-sigma stay under a tenth of their quantity's size (``determined`` eq. (4)): never a
traceback, a ComplexWarning, a complex number or a 1-sigma of 1e12 in the parameter file. A still
unit's capture (the TUI's magnetometer step before issue 31 saved one) gave ComplexWarnings and a
RepresenterError (exit 1), or, with the World Magnetic Model's field, exit 0 and A[0,0] = 1562 +/- 2.6e12.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from mocks.attitude import axis_angle_matrix, random_attitude
from mocks.mag_sessions import nine_axis_unit, sphere_session
from mocks.rig import Move, Rotation, Segment, Static, simulate
from station import cli
from station.acquisition.capture_csv import write_csv
from station.engines.magnetometer.determined import MAX_SIGMA_SHARE, reading_noise, sphere_centre
from station.errors import ExitCode

RATE_HZ = 50.0


def _session(segments: list[Segment], seed: int):
    """A capture of the simulated nine-axis unit of ``seed`` moved through ``segments``."""
    return simulate(nine_axis_unit(seed), segments, rate_hz=RATE_HZ, seed=seed).to_capture()


def _holds(attitudes: list[np.ndarray], hold_s: float = 1.0, move_s: float = 1.0) -> list[Segment]:
    segments: list[Segment] = [Static("+z", 1.0, label="")]
    for attitude in attitudes:
        segments += [Move(move_s), Static("", hold_s, label="", attitude=attitude)]
    return segments


def still(rng: np.random.Generator, seed: int):
    return _session([Static("+z", float(rng.uniform(10, 40)), label="")], seed)


def one_axis(rng: np.random.Generator, seed: int):
    axis = str(rng.choice(["+z", "-z", "+x", "+y"]))
    turns = [Rotation(axis, 360.0, 30.0), Rotation(axis, 360.0, 45.0)]
    return _session([Static("+z", 1.0, label=""), *turns], seed)


def planar(rng: np.random.Generator, seed: int):
    """Held at attitudes about one horizontal axis only: the field's directions on one circle."""
    axis = np.array([*rng.normal(size=2), 0.0])
    axis /= np.linalg.norm(axis)
    angles = np.radians(rng.uniform(-180, 180, 14))
    return _session(_holds(list(axis_angle_matrix(axis, angles))), seed)


def tiny_motion(rng: np.random.Generator, seed: int):
    """Turned by a few degrees at most: the directions in a patch the noise hides the curvature of."""
    attitudes = []
    for _ in range(12):
        axis = rng.normal(size=3)
        angle = np.radians([rng.uniform(0.2, 3.0)])
        attitudes.append(axis_angle_matrix(axis / np.linalg.norm(axis), angle)[0])
    return _session(_holds(attitudes), seed)


def tiny_values(rng: np.random.Generator, seed: int):
    """A full session in units a million times too small (tesla read as microtesla), NaN-free."""
    cap = _session(sphere_session(n_poses=10, seed=seed, hold_s=1.0, move_s=1.0), seed)
    cap.mag = cap.mag * 1e-6
    return cap


def saturated(rng: np.random.Generator, seed: int):
    """A full session clipped on every axis at a range smaller than the field."""
    cap = _session(sphere_session(n_poses=10, seed=seed, hold_s=1.0, move_s=1.0), seed)
    limit = float(rng.uniform(5, 30))
    cap.mag = np.clip(cap.mag, -limit, limit)
    return cap


def noise_only(rng: np.random.Generator, seed: int):
    """A magnetometer that reports noise and no field, the unit turning."""
    cap = _session(sphere_session(n_poses=10, seed=seed, hold_s=1.0, move_s=1.0), seed)
    cap.mag = rng.normal(0.0, float(rng.uniform(0.05, 2.0)), cap.mag.shape)
    return cap


def two_poses(rng: np.random.Generator, seed: int):
    return _session(_holds([random_attitude(rng)], hold_s=8.0), seed)


def drifting_still(rng: np.random.Generator, seed: int):
    """A still unit whose readings drift (a warming part, a car passing outside)."""
    cap = _session([Static("+z", 30.0, label="")], seed)
    cap.mag = cap.mag + np.outer(cap.t / cap.t[-1], rng.normal(0, 3, 3))
    return cap


def coarse(rng: np.random.Generator, seed: int):
    """A full session read with a 25 uT resolution."""
    cap = _session(sphere_session(n_poses=10, seed=seed, hold_s=1.0, move_s=1.0), seed)
    cap.mag = np.round(cap.mag / 25.0) * 25.0
    return cap


def few_samples(rng: np.random.Generator, seed: int):
    cap = _session(sphere_session(n_poses=10, seed=seed, hold_s=1.0, move_s=1.0), seed)
    keep = np.sort(rng.choice(len(cap.t), int(rng.integers(3, 60)), replace=False))
    for name in ("t", "acc", "gyro", "temp", "dtemp", "mag", "step"):
        value = getattr(cap, name, None)
        if value is not None:
            setattr(cap, name, value[keep])
    return cap


CASES: dict[str, Callable] = {f.__name__: f for f in (
    still, one_axis, planar, tiny_motion, tiny_values, saturated, noise_only, two_poses, drifting_still,
    coarse, few_samples)}


def _check_written(path: Path) -> None:
    """The mag section: finite real numbers, each 1-sigma under a tenth of its quantity's size."""
    section = yaml.safe_load(path.read_text())["mag"]
    a, c, b = (np.array(section[k], float) for k in ("matrix", "correction", "bias"))
    f = float(section["field_norm"])
    sd = section["stddev"]
    for value in (a, c, b, f, *(np.array(v, float) for v in sd.values())):
        assert np.all(np.isfinite(value)), section
    assert np.max(np.array(sd["matrix"])) < MAX_SIGMA_SHARE * np.linalg.norm(a, 2)
    assert np.max(np.array(sd["correction"])) < MAX_SIGMA_SHARE * np.linalg.norm(c, 2)
    assert np.max(np.array(sd["bias"])) < MAX_SIGMA_SHARE * f
    # the largest entry of each row of A, the scale it reads with, is known to better than itself
    for row, row_sd in zip(a, np.array(sd["matrix"]), strict=True):
        j = int(np.argmax(np.abs(row)))
        assert row_sd[j] < abs(row[j])


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("place", [[], ["--latitude", "45", "--longitude", "7", "--height", "200"]],
                         ids=["data-field", "wmm-field"])
def test_a_degenerate_capture_is_refused_in_one_line_or_fitted_with_finite_values(
        case: str, seed: int, place: list[str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng([seed, sorted(CASES).index(case)])
    capture = tmp_path / f"{case}.csv"
    write_csv(capture, CASES[case](rng, seed))
    params = tmp_path / "unit.yaml"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a ComplexWarning or an overflow is a failure, not a line on stderr
        code = cli.main(["calibrate", str(capture), "--method", "mag", "-o", str(params), *place])
    out, err = capsys.readouterr()
    assert code in (ExitCode.OK, 4), (code, err)
    if code == 4:
        line = err.strip()
        assert "\n" not in line and "Traceback" not in line, err
        assert "capture" in line and ("again" in line or "turn" in line), line  # says what to do
        assert not params.exists()
    else:
        _check_written(params)


def test_a_still_units_capture_names_the_noise() -> None:
    """The capture of issue 31: a still unit whose sphere through the noise saw every direction."""
    cap = _session([Static("+z", 30.0, label="")], 1)
    centre = sphere_centre(cap.mag)
    assert not centre.determined and "did not move beyond the noise" in str(centre.problem)
    assert 0.1 < centre.noise < 0.25  # the simulated unit's 0.15 uT, quantised to 0.1 uT
    assert centre.radius < 5 * centre.noise  # the sphere through the noise: about sqrt(3) sigma


def test_reading_noise_ignores_a_smooth_turn_and_held_repeats() -> None:
    t = np.arange(3000) / 100.0
    field = 50 * np.column_stack([np.cos(0.5 * t), np.sin(0.5 * t) * np.cos(0.2 * t), np.sin(0.2 * t)])
    noisy = field + np.random.default_rng(0).normal(0, 0.3, field.shape)
    assert reading_noise(noisy) == pytest.approx(0.3, rel=0.15)
    held = np.repeat(noisy[::4], 4, axis=0)  # a 25 Hz magnetometer in a 100 Hz stream
    assert reading_noise(held) == pytest.approx(0.3, rel=0.3)
