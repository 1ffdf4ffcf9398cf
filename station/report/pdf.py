"""A report page printed to PDF by headless Chromium (Debian's ``chromium``), as a browser prints it.

Chromium lays the page out with the page's own ``@media print`` rules and A4 ``@page`` size;
nothing but the HTML file is read (the pages hold no network resource).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from station.common.files import atomic_write_bytes
from station.errors import OutputFileError, StationError

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
TIMEOUT_S = 120.0


def find_browser() -> str | None:
    """The headless browser that prints the PDF: ``$IMU_STATION_CHROMIUM``, else the first of
    :data:`BROWSERS` on the PATH; None when there is none."""
    given = os.environ.get("IMU_STATION_CHROMIUM")
    if given:
        return shutil.which(given)
    return next((found for name in BROWSERS if (found := shutil.which(name))), None)


def html_to_pdf(html_path: str | Path, pdf_path: str | Path) -> None:
    """Print the page ``html_path`` to ``pdf_path`` (atomically: a PDF appears whole or not at all).

    Parameters
    ----------
    html_path : str or Path
        The report page, already written.
    pdf_path : str or Path
        Where the PDF goes.

    Raises
    ------
    StationError
        No Chromium is installed (the message says how to install it), or it failed.
    OutputFileError
        The PDF cannot be written there.
    """
    browser = find_browser()
    if browser is None:
        raise StationError(f"--pdf {pdf_path}: printing to PDF needs headless Chromium, not installed here "
                           "(Debian/Ubuntu: apt-get install chromium; or set IMU_STATION_CHROMIUM to a "
                           f"Chromium or Chrome binary); the HTML {html_path} is written")
    pdf_path = Path(pdf_path)
    try:
        pdf_path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFileError(pdf_path, f"cannot create its folder: {exc.strerror}") from None
    with tempfile.TemporaryDirectory(prefix="imu-station-pdf-") as work:
        out = Path(work) / "page.pdf"
        flags = ["--headless", "--disable-gpu", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-pdf-header-footer",
                 f"--user-data-dir={Path(work) / 'profile'}", f"--print-to-pdf={out}"]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            flags.append("--no-sandbox")  # Chromium refuses to start as root with its sandbox
        try:
            done = subprocess.run([browser, *flags, Path(html_path).resolve().as_uri()], capture_output=True,
                                  text=True, timeout=TIMEOUT_S)
        except subprocess.TimeoutExpired:
            raise StationError(f"--pdf {pdf_path}: {browser} did not finish printing within {TIMEOUT_S:g} s; "
                               f"the HTML {html_path} is written") from None
        if not out.exists() or out.stat().st_size == 0:
            tail = done.stderr.strip().splitlines()[-3:]
            raise StationError(f"--pdf {pdf_path}: {browser} printed no PDF (exit {done.returncode}: "
                               f"{' / '.join(tail) or 'no message'}); the HTML {html_path} is written")
        try:
            atomic_write_bytes(pdf_path, out.read_bytes())
        except OSError as exc:
            raise OutputFileError(pdf_path, f"cannot write the PDF: {exc.strerror}") from None
