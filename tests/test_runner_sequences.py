"""Sequences as data: the built-ins of the capture-csv spec and YAML files refused with their line."""

from __future__ import annotations

import numpy as np
import pytest

from station.acquisition.sequences import (
    PoseStep,
    RotationStep,
    SequenceError,
    builtin,
    load_yaml,
    parse_rotation,
    pose_label,
    pose_vector,
    resolve,
)
from station.errors import InputFileError


def test_builtin_six_and_twelve_position_follow_the_spec():
    six = builtin("six-position", rotations=False)
    assert six.labels == ["+x", "-x", "+y", "-y", "+z", "-z"]
    twelve = builtin("twelve-position")
    assert twelve.labels == ["+x", "-x", "+y", "-y", "+z", "-z", "+x+y", "-x-y", "+y+z", "-y-z", "+z+x",
                             "-z-x", "rot+x", "rot-x", "rot+y", "rot-y", "rot+z", "rot-z"]
    assert builtin("rotations").labels == ["rot+x", "rot-x", "rot+y", "rot-y", "rot+z", "rot-z"]
    short = builtin("six-position", hold_s=1.5, rotation_rate_dps=180.0, settle_s=0.5)
    assert all(s.hold_s == 1.5 for s in short.steps if isinstance(s, PoseStep))
    rot = [s for s in short.steps if isinstance(s, RotationStep)]
    assert all(r.rate_dps == 180.0 and r.settle_s == 0.5 for r in rot)
    # six holds of 1.5 s, six turns of 2 s each plus two settles of 0.5 s
    assert short.nominal_duration_s == pytest.approx(6 * 1.5 + 6 * (2.0 + 1.0))


def test_pose_vectors_and_labels_round_trip():
    assert np.allclose(pose_vector("+z"), [0, 0, 1])
    assert np.allclose(pose_vector("-x"), [-1, 0, 0])
    assert np.allclose(pose_vector("+x+y"), np.array([1, 1, 0]) / np.sqrt(2))
    for label in ("+x", "-y", "+x+y", "-z-x", "+x-y+z"):
        assert pose_label(pose_vector(label)) == _canonical(label)
    with pytest.raises(SequenceError, match="twice"):
        pose_vector("+x-x")
    with pytest.raises(SequenceError, match="signed axes"):
        pose_vector("up")


def _canonical(label: str) -> str:
    parts = sorted([label[i:i + 2] for i in range(0, len(label), 2)], key=lambda p: "xyz".index(p[1]))
    return "".join(parts)


def test_rotation_labels():
    assert parse_rotation("rot+z") == (2, 360.0)
    assert parse_rotation("rot-z") == (2, -360.0)
    assert parse_rotation("rot+x:180") == (0, 180.0)
    assert parse_rotation("rot-y:90.5") == (1, -90.5)
    step = RotationStep("rot-y:90", rate_dps=45.0)
    assert step.axis == 1 and step.angle_deg == -90.0 and step.start_pose == "+y"
    assert step.duration_s == pytest.approx(2.0)
    for bad in ("rot", "rotz", "rot+w", "rot+x:", "rot+x:0", "rot+x:-90"):
        with pytest.raises(SequenceError):
            parse_rotation(bad)


def test_yaml_sequence_read_back(tmp_path):
    path = tmp_path / "bench.yaml"
    path.write_text(
        "schema: imu-station/sequence/1\n"
        "name: bench-check\n"
        "hold_s: 2\n"
        "rotation_rate_dps: 120\n"
        "steps:\n"
        "  - +z\n"
        "  - {pose: -z, hold_s: 10}\n"
        "  - rot+z\n"
        "  - rotation: rot+x:180\n"
        "    rate_dps: 45\n"
        "    settle_s: 2\n")
    seq = load_yaml(path)
    assert seq.name == "bench-check"
    assert seq.labels == ["+z", "-z", "rot+z", "rot+x:180"]
    assert seq.steps[0].hold_s == 2.0 and seq.steps[1].hold_s == 10.0
    assert seq.steps[2].rate_dps == 120.0 and seq.steps[2].settle_s == 1.0
    assert seq.steps[3].rate_dps == 45.0 and seq.steps[3].settle_s == 2.0 and seq.steps[3].angle_deg == 180.0
    assert resolve(str(path)).labels == seq.labels


@pytest.mark.parametrize(("text", "line", "words"), [
    ("name: a\nsteps:\n  - +z\n  - +q\n", 4, "signed axes"),
    ("name: a\nsteps:\n  - +z\n  - {pose: -z, hold_s: -1}\n", 4, "positive number"),
    ("name: a\nsteps:\n  - +z\n  - {pose: -z, hold_s: '5'}\n", 4, "positive number"),
    ("name: a\nstep:\n  - +z\n", 2, "unknown key 'step'"),
    ("name: a\nsteps:\n  - +z\n  - rot+x:abc\n", 4, "rotation"),
    ("name: a\nsteps:\n  - +z\n  - {rotation: rot+x, speed: 3}\n", 4, "unknown step key 'speed'"),
    ("name: a\nsteps:\n  - +z\n  - +x\n  - +z\n", 5, "already at line 3"),
    ("name: a\nsteps:\n  - [1, 2]\n", 3, "a step is a label"),
    ("schema: imu-station/sequence/9\nsteps: [+z]\n", 1, "this station reads"),
    ("name: a\nsteps: [+z\n", None, "not valid YAML"),
    ("name: a\n", 1, "has no 'steps'"),
])
def test_yaml_mistakes_name_file_and_line(tmp_path, text, line, words):
    path = tmp_path / "seq.yaml"
    path.write_text(text)
    with pytest.raises(InputFileError) as info:
        load_yaml(path)
    assert words in str(info.value)
    assert str(path) in str(info.value)
    if line is not None:
        assert info.value.line == line


def test_resolve_refuses_unknown_names(tmp_path):
    with pytest.raises(InputFileError, match="neither a built-in sequence"):
        resolve("seven-position")
    with pytest.raises(InputFileError, match="does not exist"):
        resolve(str(tmp_path / "missing.yaml"))
