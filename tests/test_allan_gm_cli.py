"""``imu-station allan`` with Gauss-Markov terms: the parameter file's ``GM`` and ``valid_tau`` (read back
and checked), the ``--gm`` YAML, and Kalibr values that cover the whole model."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from mocks.rig import Static, simulate
from mocks.truth import FLICKER_FLOOR, GM_ADEV_PEAK, NoiseSpec, SensorTruth, UnitTruth
from station import cli
from station.acquisition.capture_csv import write_csv
from station.export.params.file import ParamsFile

RATE = 20.0
SIGMA, TAU_C = 3e-4, 60.0


@pytest.fixture(scope="module")
def still_csv(tmp_path_factory):
    gyro = NoiseSpec(N=[5e-4] * 3, K=[1e-6] * 3, B=[SIGMA * GM_ADEV_PEAK / FLICKER_FLOOR] * 3,
                     b_corr_time_s=TAU_C)
    accel = NoiseSpec(N=[2e-3] * 3, K=[4e-5] * 3)
    truth = UnitTruth(accel=SensorTruth(noise=accel), gyro=SensorTruth(noise=gyro), serial="SIM-GM")
    rec = simulate(truth, [Static("+z", 3 * 3600.0)], rate_hz=RATE, seed=7)
    path = tmp_path_factory.mktemp("gm") / "still.csv"
    write_csv(path, rec.to_capture())
    return path


def test_gm_terms_valid_range_gm_yaml_and_kalibr(still_csv, tmp_path, capsys):
    params, gm_file, kalibr_file = tmp_path / "unit.yaml", tmp_path / "gm.yaml", tmp_path / "imu.yaml"
    code = cli.main(["allan", str(still_csv), "-o", str(params), "--gm", str(gm_file), "--gm-rate", "200",
                     "--kalibr", str(kalibr_file), "--horizon", "500", "--force"])
    out = capsys.readouterr().out
    assert code == 0
    assert "valid for tau" in out
    noise = ParamsFile.load(params).noise  # the file passes the checker with GM and valid_tau
    gyro = noise["gyro"]
    assert len(gyro["GM"]) == 3 and len(gyro["valid_tau"]) == 3
    for axis, (lo, hi) in enumerate(gyro["valid_tau"]):
        assert lo <= 0.1 and hi >= 1000.0
        assert gyro["GM"][axis], "every gyro axis carries the injected process"
        sigma, tau_c = max(gyro["GM"][axis], key=lambda p: p[0])
        assert sigma == pytest.approx(SIGMA, rel=0.35) and tau_c == pytest.approx(TAU_C, rel=0.6)
    assert noise["accel"]["GM"] == [[], [], []] or all(isinstance(p, list) for p in noise["accel"]["GM"])

    gm = yaml.safe_load(gm_file.read_text())
    assert gm["schema"] == "imu-station/gm/1" and gm["rate_hz"] == 200.0
    first = gm["gyro"]["gx"]["GM"][0]
    assert first["phi"] == pytest.approx(math.exp(-0.005 / first["tau_c"]))
    assert first["q_d"] == pytest.approx(first["sigma"] ** 2 * (1 - first["phi"] ** 2), rel=1e-9)

    # Kalibr's random walk covers the whole model over 0.05 .. 500 s: at least the K of any axis
    kal = yaml.safe_load(kalibr_file.read_text())
    eq = gyro["filter_equivalent"]
    assert eq["horizon_s"] == [500.0] * 3 and eq["step_s"] == pytest.approx(1 / RATE)
    assert kal["gyroscope_random_walk"] == pytest.approx(max(eq["K"]), rel=1e-6)
    assert kal["gyroscope_random_walk"] >= max(k or 0.0 for k in gyro["K"] or [0.0])
    assert kal["gyroscope_noise_density"] == pytest.approx(max(eq["N"]), rel=1e-6)
    assert "equivalent to the whole model" in kalibr_file.read_text()
    tau = np.geomspace(1 / RATE, 500.0, 50)
    n_eq, k_eq = max(eq["N"]), max(eq["K"])
    # the Gauss-Markov bias alone stays under the equivalent random walk's line
    gm_avar = SIGMA**2 * (TAU_C / tau) ** 2 * (2 * tau / TAU_C - 3 + 4 * np.exp(-tau / TAU_C)
                                               - np.exp(-2 * tau / TAU_C))
    assert np.all(gm_avar <= (n_eq**2 / tau + k_eq**2 * tau / 3.0) * 1.5)
