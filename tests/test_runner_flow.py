"""The sequence runner against the simulated unit on a pseudo-terminal, read by the real serial driver.

A SimulatedOperator moves the simulated unit as each step asks; a ScriptedOperator answers the
prompts and makes the requests a person would (redo, skip, abort). Holds are short (1 s at 200 Hz)
so the suite stays quick.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers import PortLost, open_device
from mocks.device import SimDevice
from mocks.faults import FaultSpec
from mocks.pty_server import PtyServer
from station.acquisition.capture import read_capture
from station.acquisition.checks import Limits
from station.acquisition.operator import FACTORY_ANSWERS, Action, ScriptedOperator, SimulatedOperator
from station.acquisition.recorder import Recorder
from station.acquisition.runner import RecorderSink, RunOptions, SequenceRunner
from station.acquisition.sequences import PoseStep, Sequence, builtin

pytestmark = pytest.mark.timeout(180)


@pytest.fixture
def unit():
    """(server, device) of a random simulated unit at 200 Hz, on a pty opened by the serial driver.

    Its clock runs 4 times faster than the wall clock: the runner times everything on the device
    clock, so the runs are the same, only quicker.
    """
    server = PtyServer(SimDevice(seed=11, rate_hz=200.0, scenario="still"), speed=4.0).start()
    device = open_device(server.port_path)
    device.get_info()
    yield server, device
    device.close()
    server.stop()


def poses(*labels: str, hold_s: float = 0.6) -> Sequence:
    return Sequence("test", tuple(PoseStep(label, hold_s) for label in labels))


def test_six_position_and_rotations_recover_the_units_truth(unit, tmp_path):
    server, device = unit
    truth = server.device.truth
    # The six poses and two turns (both senses, two axes); the TUI tests run all six turns.
    full = builtin("six-position", hold_s=1.0, rotation_rate_dps=360.0, settle_s=0.4)
    seq = Sequence("six+2", full.steps[:6] + (full.steps[6], full.steps[11]))
    script = ScriptedOperator()
    started = time.monotonic()
    path = tmp_path / "run.csv"
    recorder = Recorder(path, device=device.info, with_step=True, port=device.port, protocol="native")
    result = SequenceRunner(device, seq, SimulatedOperator(server.device, script, move_s=0.4),
                            sink=RecorderSink(recorder, device)).run()
    recorder.close()
    assert result.outcome == "completed", result.reason
    assert result.accepted == seq.labels
    assert [s.status for s in result.steps] == ["accepted"] * len(seq)
    assert [e.event for e in script.transcript][:3] == ["begin", "confirm:start", "place"]
    # Live status reaches the operator at most ~20 times a second, however fast samples arrive.
    assert 20 < script.statuses <= 21 * (time.monotonic() - started)

    capture = result.capture
    assert [label for label, _ in capture.segments()] == seq.labels
    # Every pose step: the mean raw specific force is the truth's forward model of g up,
    # raw = M g u + b + b_T(25 degC) (the thermal bias is its constant term at t_ref).
    acc_truth = truth.accel
    for label, sl in capture.segments()[:6]:
        step = seq.steps[seq.labels.index(label)]
        thermal_at_ref = acc_truth.thermal.coeffs[:, 6]
        expected = acc_truth.matrix @ (truth.gravity * step.up) + acc_truth.bias + thermal_at_ref
        assert np.allclose(capture.acc[sl].mean(axis=0), expected, atol=0.03), label
        assert len(capture.t[sl]) >= 200
    # Every turn: the raw gyro integrates to the truth's scale times the angle (misalignment is
    # second order), within 1 %.
    assert [r.label for r in result.steps[6:]] == ["rot+x", "rot-z"]
    for record in result.steps[6:]:
        step = seq.steps[seq.labels.index(record.label)]
        scale = truth.gyro.matrix[step.axis, step.axis]
        assert record.rotation.ok
        assert record.rotation.angle_deg == pytest.approx(scale * step.angle_deg, rel=0.01), record.label
    # The streamed capture file holds the same labelled samples as the in-memory capture.
    on_disk = read_capture(path)
    assert [label for label, _ in on_disk.segments()] == seq.labels
    assert len(on_disk) == len(capture)
    assert np.allclose(on_disk.acc, capture.acc, atol=1e-6)
    assert np.array_equal(on_disk.step, capture.step)


def test_redo_and_skip_requests_and_abort_keeps_what_was_captured(unit):
    server, device = unit
    asked: list[str] = []

    def on_place(step, index, total):
        asked.append(step.label)
        if step.label == "-z" and asked.count("-z") == 1:
            script.request("redo")
        if step.label == "+x":
            script.request("skip")
        if step.label == "-x":
            script.request(Action.ABORT)

    script = ScriptedOperator(on_place=on_place)
    seq = poses("+z", "-z", "+x", "-x", "+y")
    result = SequenceRunner(device, seq, SimulatedOperator(server.device, script, move_s=0.3)).run()
    assert result.outcome == "aborted" and "aborted" in result.reason
    assert asked == ["+z", "-z", "-z", "+x", "-x"]
    status = {r.label: (r.status, r.attempts) for r in result.steps}
    assert status == {"+z": ("accepted", 1), "-z": ("accepted", 2), "+x": ("skipped", 1),
                      "-x": ("aborted", 1)}
    labels = [label for label, _ in result.capture.segments()]
    assert labels == ["+z", "-z"]
    assert len(result.capture) > 2 * 120  # the steps and the time between them are all kept
    assert result.skipped == ["+x"]
    assert result.summary().startswith("Run aborted: 2 of 5 steps captured, 1 skipped, ")


def test_failed_check_is_reviewed_redo_then_skip(unit):
    server, device = unit
    answers = iter([Action.REDO, Action.SKIP])
    prompts = []

    def review(prompt):
        prompts.append(prompt)
        return next(answers)

    script = ScriptedOperator(answers={"review": review})
    # A saturation limit below 1 g: every sample of +z counts as saturated on z.
    options = RunOptions(limits=Limits(acc_saturation=9.0))
    result = SequenceRunner(device, poses("+z"), SimulatedOperator(server.device, script), options).run()
    assert result.outcome == "completed"
    assert [p.kind for p in prompts] == ["review", "review"]
    assert "saturated" in prompts[0].details[0]
    assert prompts[0].default is Action.REDO
    assert result.steps[0].status == "skipped" and result.steps[0].attempts == 2
    assert result.capture.segments() == []  # a skipped step leaves no label
    # Out of attempts, redo is no longer offered.
    limited = RunOptions(limits=Limits(acc_saturation=9.0), max_attempts=1)
    script2 = ScriptedOperator(answers={"review": Action.ACCEPT})
    kept = SequenceRunner(device, poses("+z"), SimulatedOperator(server.device, script2), limited).run()
    assert kept.steps[0].status == "accepted" and kept.steps[0].problems
    assert [label for label, _ in kept.capture.segments()] == ["+z"]
    # The factory's answers: redo while offered, then abort; the step counts as failed.
    factory = ScriptedOperator(answers=FACTORY_ANSWERS)
    two = RunOptions(limits=Limits(acc_saturation=9.0), max_attempts=2)
    failed = SequenceRunner(device, poses("+z"), SimulatedOperator(server.device, factory), two).run()
    assert failed.outcome == "aborted" and "saturated" in failed.reason
    assert (failed.steps[0].status, failed.steps[0].attempts) == ("failed", 2)
    assert [e.detail for e in factory.transcript if e.event == "confirm:review"] == ["redo", "abort"]
    with pytest.raises(ValueError, match="not one of"):
        SequenceRunner(device, poses("+z"), SimulatedOperator(server.device, ScriptedOperator(
            answers={"review": "redo"})), limited).run()


def test_timeout_prompt_for_a_unit_nobody_moves(unit):
    _, device = unit
    script = ScriptedOperator(answers={"timeout": Action.ABORT})
    result = SequenceRunner(device, poses("-z"), script, RunOptions(step_timeout_s=1.0)).run()
    assert result.outcome == "timeout"
    assert "not in pose" in result.reason and "-z" in result.reason
    assert result.steps[0].status == "aborted"
    assert len(result.capture) >= 150  # the wait (a wall second, 4 s of device clock) is kept, unlabelled
    assert result.capture.segments() == []


def test_dropouts_are_reported_and_a_lost_link_keeps_the_capture():
    faults = FaultSpec(drop=0.05, disconnect_after_s=4.0, seed=3)
    server = PtyServer(SimDevice(seed=5, rate_hz=200.0, scenario="still"), faults=faults).start()
    device = open_device(server.port_path)
    try:
        script = ScriptedOperator(answers={"review": Action.ACCEPT})
        seq = poses("+z", "-z", "+x", "-x", "+y", "-y", hold_s=1.0)
        result = SequenceRunner(device, seq, SimulatedOperator(server.device, script, move_s=0.3)).run()
    finally:
        device.close()
        server.stop()
    assert result.outcome == "link-error"
    assert isinstance(result.error, PortLost)
    first = result.steps[0]
    assert first.label == "+z" and first.status == "accepted"
    assert first.dropouts.lost > 0 and any("lost" in p for p in first.problems)
    assert result.steps[-1].status == "aborted"
    assert [label for label, _ in result.capture.segments()][0] == "+z"
    assert result.capture.link["lost"] >= first.dropouts.lost


def test_twelve_position_diagonal_poses_are_reached_and_labelled():
    server = PtyServer(SimDevice(seed=5, rate_hz=200.0, scenario="still"), speed=8.0).start()
    device = open_device(server.port_path)
    try:
        seq = builtin("twelve-position", rotations=False, hold_s=1.0)
        result = SequenceRunner(device, seq, SimulatedOperator(server.device, ScriptedOperator())).run()
    finally:
        device.close()
        server.stop()
    assert result.outcome == "completed" and result.accepted == seq.labels
    truth, g = server.device.truth.accel, server.device.truth.gravity
    for (label, sl), step in zip(result.capture.segments(), seq.steps, strict=True):
        assert label == step.label
        expected = truth.matrix @ (g * step.up) + truth.bias + truth.thermal.coeffs[:, 6]
        assert np.allclose(result.capture.acc[sl].mean(axis=0), expected, atol=0.03), label
