"""``imu-station capture --protocol frame:FILE.yaml`` through a real pty: a board's own frames, with noise
and damaged frames on the line, recorded and read back; and the Python API (``open_device``)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import yaml
from device_helpers import BytePty
from frame_helpers import SPEC_EXAMPLE, damaged_stream, plain_frames, still_samples

from drivers import open_device
from protocols.frame_description import describe
from station.acquisition.capture import read_capture
from station.cli import main


def test_capture_records_a_boards_own_frames_through_a_pty(tmp_path: Path, capsys) -> None:
    desc_file = tmp_path / "acme.yaml"
    desc_file.write_text(yaml.safe_dump(SPEC_EXAMPLE), encoding="utf-8")
    desc = describe(SPEC_EXAMPLE)
    sent = still_samples(1200, 200.0, seed=5)
    stream, _ = damaged_stream(plain_frames(desc, sent), desc.length, seed=5)
    out = tmp_path / "acme.csv"
    # 200 frames a second, written 10 at a time, cut anywhere by the pty.
    with BytePty.chunked(stream, chunk=10 * desc.length + 3, period_s=0.05) as pty:
        code = main(["capture", "--port", pty.path, "--protocol", f"frame:{desc_file}", "--duration", "1",
                     "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0, err
    cap = read_capture(out)
    assert 180 <= len(cap) <= 220
    index = np.round(cap.t * 200.0).astype(int)  # t is the board's clock: 5 ms a sample from 0
    np.testing.assert_allclose(cap.acc, sent["acc"][index], atol=0.0024)  # one count of the i16 scale
    np.testing.assert_allclose(cap.gyro, sent["gyro"][index], atol=0.00027)
    np.testing.assert_allclose(cap.temp, sent["temp"][index], atol=0.006)


def test_a_shipped_description_by_name_and_the_python_api(tmp_path: Path) -> None:
    import station.frames.reader  # noqa: F401  (installs the reader of frame: descriptions, as the CLI does)

    stream = (Path(__file__).parent / "data" / "frames" / "mpu6050_dump.bin").read_bytes()
    with BytePty.chunked(stream, chunk=500, period_s=0.01, delay_s=0.5) as pty:
        with open_device(pty.path, protocol="frame:mpu6050_dump") as device:
            got, deadline = [], time.monotonic() + 5.0
            while sum(len(g) for g in got) < 590 and time.monotonic() < deadline:
                got.append(device.read(timeout=0.2))
            stats = device.stats
    samples = np.concatenate(got)
    assert len(samples) >= 590
    assert np.allclose(np.linalg.norm(samples["acc"], axis=1), 9.81, atol=0.2)
    assert stats.lost == 2  # the counter's gaps (frames 10 and 20 of the recording)


def test_a_capture_file_names_the_description_not_its_file(tmp_path: Path, capsys) -> None:
    import h5py

    desc_file = tmp_path / "board-file.yaml"
    desc_file.write_text(yaml.safe_dump(SPEC_EXAMPLE), encoding="utf-8")
    desc = describe(SPEC_EXAMPLE)
    out = tmp_path / "acme.h5"
    with BytePty.chunked(plain_frames(desc, still_samples(600, 200.0, seed=6)), chunk=4 * desc.length,
                 period_s=0.02) as pty:
        code = main(["capture", "--port", pty.path, "--protocol", f"frame:{desc_file}", "--duration", "0.5",
                     "-o", str(out)])
    assert code == 0, capsys.readouterr().err
    with h5py.File(out, "r") as f:
        assert f.attrs["protocol"] == f"frame:{SPEC_EXAMPLE['name']}"
        assert f.attrs["port"] == pty.path
    assert len(read_capture(out)) >= 90


def test_the_tui_connect_screen_offers_and_shows_the_frame_protocol(tmp_path: Path) -> None:
    import asyncio

    from tui_helpers import screen_text, wait_for

    import station.frames.reader  # noqa: F401  (installs the reader of frame: descriptions, as the CLI does)
    from station.tui.app import StationApp
    from station.tui.config import TuiConfig

    desc_file = tmp_path / "acme.yaml"
    desc_file.write_text(yaml.safe_dump(SPEC_EXAMPLE), encoding="utf-8")
    desc = describe(SPEC_EXAMPLE)
    given = f"frame:{desc_file}"

    async def run(app: StationApp) -> None:
        async with app.run_test(size=(160, 40)) as pilot:
            await wait_for(pilot, lambda: "frame:acme-imu-v2" in screen_text(app), 10, "the board's frames")
            seen = []
            for _ in range(6):  # the registry's five protocols and the description given
                await pilot.press("p")
                seen.append(app.config.protocol)
            assert seen[-1] == given and given not in seen[:-1] and "native" in seen
            assert given in screen_text(app)
            # The whole stream read before the port closes (the test's writer would block on a full pty).
            await wait_for(pilot, lambda: not pty._thread.is_alive(), 15, "the end of the stream")
            app.exit(0)

    with BytePty.chunked(plain_frames(desc, still_samples(400, 200.0, seed=7)), chunk=4 * desc.length,
                 period_s=0.02) as pty:
        app = StationApp(TuiConfig(port=pty.path, protocol=given))
        asyncio.run(run(app))
