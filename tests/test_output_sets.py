"""A command's files appear together or not at all; SIGTERM is handled as Ctrl-C; no temporary file stays.

The set is checked three ways: the staging itself (``station.common.files.output_set``), commands
whose last writer fails after the first files were written (the old files must all stay, no
``.tmp`` left), and real processes stopped by SIGTERM while they write (exit 143, the files old
or new together).
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from export_params import make_params

from mocks.rig import Static, simulate
from mocks.truth import NoiseSpec, SensorTruth, UnitTruth
from station import cli
from station.acquisition.capture_csv import write_csv
from station.common.files import atomic_write_text, output_set, staged_path
from station.errors import ExitCode
from station.export.params.file import ParamsFile

CLI = [str(Path(sys.executable).with_name("imu-station"))]


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*") if p.name.endswith(".tmp") or ".tmp." in p.name)


def test_a_set_appears_whole_when_its_block_ends(tmp_path: Path) -> None:
    a, b = tmp_path / "a.txt", tmp_path / "sub" / "b.txt"
    with output_set() as outputs:
        atomic_write_text(a, "new a")
        assert not a.exists(), "a file of the set appeared before the set was whole"
        assert staged_path(a).read_text() == "new a" and outputs.staged(b) == b
        atomic_write_text(b, "first b")
        atomic_write_text(b, "new b")  # written twice: the second wins, the first temporary goes
    assert (a.read_text(), b.read_text()) == ("new a", "new b")
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt, OSError])
def test_a_set_that_fails_leaves_every_old_file(tmp_path: Path, interrupt: type[BaseException]) -> None:
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old a")
    with pytest.raises(interrupt), output_set():
        atomic_write_text(a, "new a")
        atomic_write_text(b, "new b")
        raise interrupt()
    assert a.read_text() == "old a" and not b.exists()
    assert leftovers(tmp_path) == []


def test_a_signal_while_the_set_is_renamed_waits_until_it_is_whole(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    files = [tmp_path / f"f{i}.txt" for i in range(5)]
    seen: list[bool] = []  # at the signal's handling: was every file of the set in place?
    real_replace = os.replace

    def replace_with_a_signal(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        if not seen and not any(p.exists() for p in files):
            signal.raise_signal(signal.SIGINT)  # Ctrl-C as the first rename begins
        real_replace(src, dst)

    def handler(signum: int, frame: object) -> None:
        seen.append(all(p.exists() for p in files))

    original = signal.signal(signal.SIGINT, handler)
    try:
        with output_set():
            for path in files:
                atomic_write_text(path, "new")
            monkeypatch.setattr(os, "replace", replace_with_a_signal)
    finally:
        monkeypatch.undo()
        signal.signal(signal.SIGINT, original)
    assert seen == [True], "the signal was handled before every file of the set was in place"


# ---- commands: the last writer fails, every old file stays ----------------------------------------

@pytest.fixture(scope="module")
def still_csv(tmp_path_factory) -> Path:
    noise = NoiseSpec(N=[3e-4] * 3, K=[2e-5] * 3)
    truth = UnitTruth(accel=SensorTruth(noise=NoiseSpec(N=[2e-3] * 3)), gyro=SensorTruth(noise=noise),
                      serial="SIM-SET")
    path = tmp_path_factory.mktemp("sets") / "still.csv"
    write_csv(path, simulate(truth, [Static("+z", 600.0)], rate_hz=100.0, seed=3).to_capture())
    return path


def test_allan_interrupted_at_its_last_file_leaves_the_old_set(still_csv: Path, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    from station.export.params import file as params_file

    params, kalibr, curve = tmp_path / "unit.yaml", tmp_path / "kalibr.yaml", tmp_path / "curve.csv"
    ParamsFile(device={"serial": "SIM-SET"}).save(params)
    kalibr.write_text("old kalibr")
    before = {p: p.read_bytes() for p in (params, kalibr)}

    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt  # Ctrl-C as the parameter file, written last, is about to be written

    monkeypatch.setattr(params_file, "merge_sections", interrupted)
    code = cli.main(["allan", str(still_csv), "--force", "--kalibr", str(kalibr), "--curve", str(curve),
                     "-o", str(params)])
    assert code == ExitCode.INTERRUPTED, capsys.readouterr().err
    assert {p: p.read_bytes() for p in (params, kalibr)} == before  # the old Kalibr file stays
    assert not curve.exists() and leftovers(tmp_path) == []


def test_export_c_failing_at_its_last_file_leaves_the_old_unit(tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    from station.export.firmware import c_source

    old, new, out = tmp_path / "old.yaml", tmp_path / "new.yaml", tmp_path / "c"
    make_params(seed=1, device={"serial": "SN-OLD"}).save(old)
    make_params(seed=2, device={"serial": "SN-NEW"}).save(new)
    assert cli.main(["export", str(old), "-f", "c", "-o", str(out)]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert len(before) >= 3

    real = c_source.atomic_write_bytes

    def full_disk_at_the_blob(path: str | Path, data: bytes) -> None:
        if str(path).endswith(".bin"):
            raise OSError(28, "No space left on device")
        real(path, data)

    monkeypatch.setattr(c_source, "atomic_write_bytes", full_disk_at_the_blob)
    with pytest.raises(OSError):
        cli.main(["export", str(new), "-f", "c", "-o", str(out)])
    capsys.readouterr()
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # no new header beside the old blob


# ---- real processes stopped by SIGTERM --------------------------------------------------------------

def _wait_for_start(proc: subprocess.Popen[str], delay_s: float) -> None:
    deadline = time.monotonic() + delay_s
    while time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.005)  # the point is a signal at a given moment of the run, not waiting on a condition


@pytest.mark.parametrize("delay_s", [0.3, 0.6, 0.9, 1.2, 1.5, 1.8])
def test_allan_stopped_by_sigterm_keeps_its_files_together(still_csv: Path, tmp_path: Path,
                                                          delay_s: float) -> None:
    params, kalibr, plot = tmp_path / "unit.yaml", tmp_path / "kalibr.yaml", tmp_path / "allan.png"
    ParamsFile(device={"serial": "SIM-SET"}).save(params)
    kalibr.write_text("old kalibr")
    proc = subprocess.Popen([*CLI, "allan", str(still_csv), "--force", "--kalibr", str(kalibr),
                             "--plot", str(plot), "-o", str(params)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_start(proc, delay_s)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert "Traceback" not in err, err
    new_kalibr = kalibr.read_text() != "old kalibr"
    has_noise = "\nnoise:" in params.read_text()
    if proc.returncode == 0:  # it finished before the signal
        assert new_kalibr and has_noise and plot.exists()
    else:
        assert proc.returncode == ExitCode.TERMINATED, err
        assert "terminated" in err
        assert new_kalibr == has_noise == plot.exists(), "a partial set of files"
    assert leftovers(tmp_path) == []


def test_sigterm_is_handled_as_ctrl_c_by_a_capture(tmp_path: Path) -> None:
    from mocks.pty_server import PtyServer
    from station.acquisition.capture import read_capture

    out = tmp_path / "cap.csv"
    with PtyServer(seed=4, rate_hz=200) as server:
        proc = subprocess.Popen([*CLI, "capture", "--port", server.port_path, "--duration", "60",
                                 "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30
        while server.device_time_s() < 1.0 and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.02)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == ExitCode.TERMINATED, err
    assert "Traceback" not in err
    assert len(read_capture(out)) > 0 and np.all(np.diff(read_capture(out).t) > 0)
    assert leftovers(tmp_path) == []
