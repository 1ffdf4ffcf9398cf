"""The figures of a calibration across temperature: the scale factor's temperature coefficient (ppm/degC)
and the misalignment's change over the range (urad), from ``thermal.scale`` and ``thermal.misalignment``,
checked against closed forms and numpy's own polynomial fit, in the table that ``characterise
--datasheet`` prints and in the certificate with its plot (rendered in headless Chromium)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from across_temperature_params import MISALIGNMENT, SCALE, T_MAX, T_MIN, T_REF, campaign_file
from report_helpers import check_page, not_blank, screenshot
from report_helpers import cli as run_cli

from station import cli
from station.engines.thermal.intrinsics import OFF_DIAGONAL
from station.report.datasheet import datasheet_rows


@pytest.fixture
def unit_file(tmp_path):
    return campaign_file(tmp_path / "unit.yaml")


def test_scale_temperature_coefficient_is_the_least_squares_slope_in_ppm(unit_file) -> None:
    doc = yaml.safe_load(unit_file.read_text())
    rows = {r.figure: r for r in datasheet_rows(doc)}
    row = rows["gyro scale-factor temperature coefficient"]
    k = np.asarray(doc["gyro"]["scale"], float)
    # Closed form: the least-squares slope of c1 t + c2 t^2 over temperatures spread evenly on [a, b] is
    # c1 + 2 c2 (mean T - T_ref).
    closed = (SCALE[:, 0] + 2.0 * SCALE[:, 1] * ((T_MIN + T_MAX) / 2 - T_REF)) / k * 1e6
    assert row.unit == "ppm/degC"
    assert row.values == pytest.approx(closed, rel=1e-9)
    temp = np.linspace(T_MIN, T_MAX, 101)
    t = temp - T_REF
    for i in range(3):
        slope = np.polynomial.polynomial.polyfit(temp, SCALE[i, 0] * t + SCALE[i, 1] * t**2, 1)[1]
        assert row.values[i] == pytest.approx(slope / k[i] * 1e6, rel=1e-9)
    assert "accel scale-factor temperature coefficient" not in rows  # only the gyro was calibrated so


def test_misalignment_change_over_the_range_in_microradians(unit_file) -> None:
    rows = {r.figure: r for r in datasheet_rows(yaml.safe_load(unit_file.read_text()))}
    row = rows["gyro misalignment change over temperature"]
    change = np.zeros((3, 3))
    for c, (i, j) in enumerate(OFF_DIAGONAL):
        change[i, j] = abs(MISALIGNMENT[c, 0]) * (T_MAX - T_MIN)  # linear: the change is |slope| x range
    assert row.unit == "urad"
    assert row.values == pytest.approx(np.sqrt((change**2).sum(axis=1)) * 1e6, rel=1e-9)


def test_campaign_turn_ons_per_soak_and_hysteresis_in_datasheet_units(unit_file) -> None:
    rows = {r.figure: r for r in datasheet_rows(yaml.safe_load(unit_file.read_text()))}
    deg = 180.0 / np.pi
    assert rows["gyro turn-on bias repeatability at -20 degC"].values == pytest.approx(
        [1e-4 * deg, 2e-4 * deg, 3e-4 * deg])
    assert rows["accel turn-on bias repeatability at 60 degC"].unit == "mg"
    assert rows["accel turn-on bias repeatability at 60 degC"].values == pytest.approx(
        [5e-3 / 9.80665 * 1e3, 6e-3 / 9.80665 * 1e3, 7e-3 / 9.80665 * 1e3])
    hysteresis = rows["gyro bias hysteresis (up - down)"]
    assert hysteresis.unit == "deg/h" and hysteresis.values == pytest.approx([1e-5 * deg * 3600, 0.0,
                                                                             -2e-5 * deg * 3600])
    assert rows["accel bias hysteresis, largest"].values[1] == pytest.approx(4e-3 / 9.80665 * 1e3)
    assert "70 bins of 1 degC over -15.0..55.0 degC" in hysteresis.measured_by


def test_characterise_datasheet_prints_the_figures(unit_file, capsys) -> None:
    assert cli.main(["characterise", "--datasheet", "--params", str(unit_file)]) == 0
    out = capsys.readouterr().out
    assert "gyro scale-factor temperature coefficient" in out and "ppm/degC" in out
    assert "gyro misalignment change over temperature" in out
    assert cli.main(["characterise", "--datasheet", "--params", str(unit_file), "--json"]) == 0
    table = {r["figure"]: r for r in json.loads(capsys.readouterr().out)["datasheet"]["rows"]}
    assert table["gyro misalignment change over temperature"]["values"][2] == pytest.approx(
        np.hypot(4e-6, 1e-6) * (T_MAX - T_MIN) * 1e6)

@pytest.mark.parametrize(("field", "value", "says"), [
    ("coeffs", [[1e-4, 0.0]] * 2, "'thermal.scale.gyro.coeffs': must be a list of 3 lists"),
    ("powers", [1, 4], "'thermal.scale.gyro.powers': must list distinct powers of t among 1, 2 and 3"),
    ("clamp", [60, -20], "'thermal.scale.gyro.clamp': [60, -20] degC is not a range"),
    ("stddev", [[1e-6, 0.0], [1e-6, -1e-7], [0.0, 0.0]],
     "'thermal.scale.gyro.stddev[1][1]': -1e-07 is negative"),
])
def test_a_broken_polynomial_is_refused_naming_file_line_and_field(unit_file, capsys, field, value,
                                                                   says) -> None:
    doc = yaml.safe_load(unit_file.read_text())
    doc["thermal"]["scale"]["gyro"][field] = value
    unit_file.write_text(yaml.safe_dump(doc))
    assert cli.main(["export", "-f", "c", str(unit_file), "-o", str(unit_file.parent / "c")]) == 4
    err = capsys.readouterr().err
    assert str(unit_file) in err and ", line " in err and says in err


def test_the_certificate_shows_the_figures_and_their_plot(unit_file) -> None:
    done = run_cli("report", str(unit_file), "-o", "unit.html", cwd=unit_file.parent)
    assert done.returncode == 0, done.stderr
    text = check_page(unit_file.parent / "unit.html")
    assert "Scale factor and misalignment against temperature" in text
    assert "Turn-on repeatability across temperature" in text and "bias hysteresis (up - down)" in text
    assert "gyro scale-factor temperature coefficient" in text and "ppm/degC" in text
    assert "gyro misalignment change over temperature" in text
    plot = text.split("Scale factor and misalignment against temperature", 1)[1]
    assert plot.index("<svg") < plot.index("</svg>")  # the figure itself, right after its title
    not_blank(screenshot(unit_file.parent / "unit.html", unit_file.parent))
