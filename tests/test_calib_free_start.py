"""The hand-held method names the real cause when a session does not start still, instead of
"too few static intervals" (what the detector then finds, with the move as its noise reference)."""

from __future__ import annotations

import pytest

from mocks.rig import handheld_session, simulate
from mocks.truth import UnitTruth
from station import cli
from station.acquisition.capture_csv import write_csv


@pytest.mark.parametrize("still_s", [0.0, 0.3])
def test_a_session_that_starts_moving_says_so(still_s, tmp_path, capsys) -> None:
    segments = handheld_session(n_poses=14, seed=3, initial_still_s=still_s or 10.0)
    if still_s == 0.0:
        segments = segments[1:]  # the first move straight away
    path = tmp_path / "handheld.csv"
    write_csv(path, simulate(UnitTruth.random(5), segments, rate_hz=100.0, seed=3).to_capture())
    for extra in ([], ["--initial-still", "5"]):
        assert cli.main(["calibrate", str(path), "--method", "free", *extra]) == 4
        err = capsys.readouterr().err
        assert "does not start still" in err and "too few static intervals" not in err, err
        assert "lying still for the first 10 s" in err
        assert ("given --initial-still period (5.0 s)" in err) == bool(extra)


def test_a_session_that_starts_still_calibrates(tmp_path, capsys) -> None:
    path = tmp_path / "handheld.csv"
    truth = UnitTruth.random(5)
    write_csv(path, simulate(truth, handheld_session(n_poses=14, seed=3), rate_hz=100.0, seed=3).to_capture())
    assert cli.main(["calibrate", str(path), "--method", "free"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("free calibration, g = 9.806650 m/s^2") and "accel: free (Tedaldi 2014)" in out
