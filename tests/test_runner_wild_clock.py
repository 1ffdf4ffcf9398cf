"""Wild device timestamps during a sequence: the runner reads through the same clock guard as a
capture, so a sample dated an hour ahead no longer breaks a step's timing, stillness window or
turn angle, and a unit that restarts its clock mid-run is bridged and reported. A simulated unit
with a faulty-clock encoder, on a real pty read by the serial driver, moved by a SimulatedOperator.
"""

from __future__ import annotations

import numpy as np
import pytest
from clock_faults import restarting_clock, wild_clock

from drivers import open_device
from mocks.device import ENCODERS, SimDevice
from mocks.pty_server import PtyServer
from station.acquisition.capture import read_capture
from station.acquisition.operator import ScriptedOperator, SimulatedOperator
from station.acquisition.recorder import Recorder
from station.acquisition.runner import RecorderSink, RunResult, SequenceRunner
from station.acquisition.sequences import PoseStep, Sequence, builtin

pytestmark = pytest.mark.timeout(180)

WILD_EVERY = 97  # one sample in 97 (about 0.5 s at 200 Hz) dated an hour ahead: one in every hold
RESTART_SEQ = 1400  # where the unit restarts (7 s of its clock): its clock and counter start again


@pytest.fixture(autouse=True)
def _faulty_clock_encoders(monkeypatch) -> None:
    """The faulty clocks, registered only while a test of this file runs."""
    monkeypatch.setitem(ENCODERS, "native-wild-clock-runner", wild_clock(WILD_EVERY, WILD_EVERY // 2))
    monkeypatch.setitem(ENCODERS, "native-restart-runner", restarting_clock(RESTART_SEQ))


def sequence() -> Sequence:
    """+z, -z and one full turn about +x (rot+x), as tests/test_runner_flow.py builds them."""
    full = builtin("six-position", hold_s=1.0, rotation_rate_dps=360.0, settle_s=0.4)
    return Sequence("wild", (PoseStep("+z", 1.0), PoseStep("-z", 1.0), full.steps[6]))


def run(encoder: str, path) -> tuple[RunResult, SimDevice, SequenceRunner]:
    sim = SimDevice(seed=11, rate_hz=200.0, scenario="still", encoder=encoder)
    with PtyServer(sim, speed=4.0) as server, open_device(server.port_path) as device:
        device.get_info()
        recorder = Recorder(path, device=device.info, with_step=True, port=device.port, protocol="native")
        seq = sequence()
        runner = SequenceRunner(device, seq, SimulatedOperator(server.device, ScriptedOperator(), move_s=0.3),
                                sink=RecorderSink(recorder, device))
        try:
            result = runner.run()
        finally:
            recorder.close(runner.link_stats().as_dict())  # as the TUI, the factory run and the demo do
    return result, sim, runner


def assert_every_step_right(result: RunResult, sim: SimDevice) -> None:
    seq = result.sequence
    assert result.outcome == "completed", result.reason
    assert [s.status for s in result.steps] == ["accepted"] * len(seq)
    assert all(s.ok for s in result.steps), [s.problems for s in result.steps]
    for record in result.steps:
        assert record.dropouts.lost == 0, record.label
        if record.kind == "pose":
            # A second of the unit's clock, neither cut short by a wild sample nor an hour long; a hold ends
            # with the read that completes it, which on a loaded machine holds a few hundred ms of samples.
            assert record.pose.ok and 1.0 <= record.duration_s < 2.0, (record.label, record.duration_s)
    turn = result.steps[2]
    scale = sim.truth.gyro.matrix[0, 0]
    assert turn.rotation.ok
    assert turn.rotation.angle_deg == pytest.approx(scale * seq.steps[2].angle_deg, rel=0.01)
    capture = result.capture
    assert [label for label, _ in capture.segments()] == seq.labels
    assert (np.diff(capture.t) > 0).all()
    for label, sl in capture.segments():  # every labelled step is a second of clock at 200 Hz, or more
        assert capture.t[sl][-1] - capture.t[sl][0] < 5.0 and len(capture.t[sl]) >= 195, label


def test_samples_an_hour_ahead_are_left_out_counted_and_every_step_accepted(tmp_path):
    """Before: the first wild sample emptied the stillness window and ended the hold at once."""
    result, sim, runner = run("native-wild-clock-runner", tmp_path / "run.csv")
    assert_every_step_right(result, sim)
    capture = result.capture
    assert not (capture.t > 3000).any()  # no sample of the hour ahead was kept
    outliers = capture.link["clock_outliers"]
    # One in WILD_EVERY of the samples received, each left out (the run's last one may be unseen).
    assert outliers >= 1 and abs(outliers - (len(capture) + outliers) / WILD_EVERY) <= 1
    # Each left out where it was: the kept samples are a period apart, or two around a wild one.
    steps_us = np.round(np.diff(capture.t) * 1e6)
    assert set(steps_us.tolist()) == {5000.0, 10000.0}
    assert abs(int((steps_us == 10000).sum()) - outliers) <= 1
    assert capture.link["clock_jumps"] == 0 and not runner.guard.jumps
    assert f"{outliers} clock outlier" in runner.link_stats().summary()
    on_disk = read_capture(tmp_path / "run.csv")
    assert [label for label, _ in on_disk.segments()] == result.sequence.labels
    assert len(on_disk) == len(capture) and np.array_equal(on_disk.step, capture.step)


def test_a_unit_restarting_its_clock_mid_run_is_a_reported_jump_and_the_run_completes(tmp_path):
    """Before: the clock went back 7 s, the window and the timing saw negative time, and the
    reset ``seq`` counted four billion samples lost."""
    result, sim, runner = run("native-restart-runner", tmp_path / "run.h5")
    assert_every_step_right(result, sim)
    assert result.capture.link["clock_jumps"] == 1 and result.capture.link["clock_outliers"] == 0
    assert read_capture(tmp_path / "run.h5").link["clock_jumps"] == 1  # the file keeps the count
    jump = runner.guard.jumps[0]
    assert jump.step_s == pytest.approx(-(RESTART_SEQ * 0.005 - 0.001), abs=0.006)
    assert "went back" in jump.describe()
    assert "1 clock jump" in runner.link_stats().summary()
    # The unit really restarted during the run, not after it: samples of both clocks are kept.
    assert len(result.capture) > RESTART_SEQ
