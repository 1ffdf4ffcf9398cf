"""The PDF printer is the second line of defence: a page where a value escaped its escaping (a script,
remote images and style sheets, a frame of a local file) prints without running, fetching or reading
anything; Chromium does not outlive the command; its temporary folders go on every way out.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest
from report_helpers import chromium

from station import cli
from station.engines.shared.sensor_model import SensorCalibration
from station.export.params.file import ParamsFile
from station.report import pdf

SECRET = "imu-station-secret-7f3a"  # in a local file the injected page tries to show


class Listener:
    """A loopback TCP port that counts the connections made to it (a fetch would be one)."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.connections = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.connections += 1
            conn.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.sock.close()


def hostile_page(folder: Path, port: int, csp: bool = True) -> Path:
    """A real certificate with, after its <body>, what an escaping failure would let through."""
    chromium()
    ParamsFile(device={"serial": "HOSTILE-1"}, accel=SensorCalibration.identity()).save(folder / "u.yaml")
    assert cli.main(["report", str(folder / "u.yaml"), "-o", str(folder / "page.html")]) == 0
    secret = folder / "secret.txt"
    secret.write_text(SECRET)
    inject = (f"<script>document.body.insertAdjacentText('afterbegin', 'SCRIPT-RAN');"
              f"fetch('http://127.0.0.1:{port}/js')</script>"
              f"<img src=\"http://127.0.0.1:{port}/img.png\"><img src=\"http://imu-station-test.invalid/x.png\">"
              f"<link rel=\"stylesheet\" href=\"http://127.0.0.1:{port}/style.css\">"
              f"<iframe src=\"{secret.as_uri()}\" width=600 height=200></iframe>"
              f"<object data=\"{secret.as_uri()}\" type=\"text/plain\"></object>")
    page = folder / "page.html"
    text = page.read_text(encoding="utf-8")
    if not csp:
        start = text.index('<meta http-equiv="Content-Security-Policy"')
        text = text[:start] + text[text.index(">", start) + 1:]
    body = text.index(">", text.index("<body")) + 1
    page.write_text(text[:body] + inject + text[body:], encoding="utf-8")
    return page


def pdf_text(path: Path) -> str:
    tool = shutil.which("pdftotext")
    if tool is None:
        pytest.skip("pdftotext is not installed (Debian: apt-get install poppler-utils)")
    done = subprocess.run([tool, str(path), "-"], capture_output=True, text=True, check=True, timeout=60)
    return done.stdout


@pytest.mark.parametrize("csp", [True, False], ids=["with-the-pages-policy", "without-it"])
def test_an_injected_page_prints_without_running_fetching_or_reading(tmp_path: Path, csp: bool) -> None:
    listener = Listener()
    try:
        page = hostile_page(tmp_path, listener.port, csp)
        pdf.html_to_pdf(page, tmp_path / "page.pdf")
    finally:
        listener.close()
    text = pdf_text(tmp_path / "page.pdf")
    assert "HOSTILE-1" in text  # the certificate itself printed
    assert "SCRIPT-RAN" not in text, "the page's script ran"
    assert SECRET not in text, "a local file was read into the PDF"
    assert listener.connections == 0, f"{listener.connections} fetches from the page"


def test_every_page_carries_the_policy(tmp_path: Path) -> None:
    ParamsFile(device={"serial": "P-1"}, accel=SensorCalibration.identity()).save(tmp_path / "u.yaml")
    assert cli.main(["report", str(tmp_path / "u.yaml"), "-o", str(tmp_path / "c.html")]) == 0
    text = (tmp_path / "c.html").read_text(encoding="utf-8")
    assert f'<meta http-equiv="Content-Security-Policy" content="{pdf.POLICY}">' in text


def test_the_printer_runs_locked_down() -> None:
    flags = pdf.browser_flags(Path("/w"), Path("/w/page.pdf"))
    assert "--host-resolver-rules=MAP * ~NOTFOUND" in flags
    assert "--user-data-dir=/w/profile" in flags
    assert pdf.with_policy("<html><HEAD lang=en><script>").startswith(
        f'<html><HEAD lang=en><meta http-equiv="Content-Security-Policy" content="{pdf.POLICY}"><script>')


def _chromium_children(parent: int) -> list[int]:
    """Processes whose command line names the page's work folder of ``parent``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if f"{pdf.WORK_PREFIX}{parent}-".encode() in cmdline:
            found.append(int(entry.name))
    return found


def test_sigterm_while_printing_kills_chromium_and_removes_its_folder(tmp_path: Path) -> None:
    chromium()
    ParamsFile(device={"serial": "T-1"}, accel=SensorCalibration.identity()).save(tmp_path / "u.yaml")
    proc = subprocess.Popen([str(Path(sys.executable).with_name("imu-station")), "report",
                             str(tmp_path / "u.yaml"), "-o", str(tmp_path / "c.html"), "--pdf",
                             str(tmp_path / "c.pdf")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not _chromium_children(proc.pid) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    if proc.poll() is not None:
        pytest.fail(f"the report ended before Chromium was seen: {proc.communicate()}")
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert "Traceback" not in err
    deadline = time.monotonic() + 10
    while _chromium_children(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _chromium_children(proc.pid) == [], "Chromium outlived the command"
    assert not list(Path(tempfile.gettempdir()).glob(f"{pdf.WORK_PREFIX}{proc.pid}-*"))
    assert not (tmp_path / "c.html").exists() and not (tmp_path / "c.pdf").exists()  # the set: neither


def test_a_folder_left_by_a_killed_command_is_removed_by_the_next_print(tmp_path: Path) -> None:
    chromium()
    dead = subprocess.Popen(["true"])
    dead.wait()
    stale = Path(tempfile.mkdtemp(prefix=f"{pdf.WORK_PREFIX}{dead.pid}-"))
    (stale / "profile").mkdir()
    mine = Path(tempfile.mkdtemp(prefix=f"{pdf.WORK_PREFIX}{os.getpid()}-"))  # a live process's: kept
    try:
        ParamsFile(device={"serial": "S-1"}, accel=SensorCalibration.identity()).save(tmp_path / "u.yaml")
        assert cli.main(["report", str(tmp_path / "u.yaml"), "-o", str(tmp_path / "c.html"),
                         "--pdf", str(tmp_path / "c.pdf")]) == 0
        assert not stale.exists() and mine.exists()
    finally:
        shutil.rmtree(mine, ignore_errors=True)
        shutil.rmtree(stale, ignore_errors=True)
