"""A report page printed to PDF by headless Chromium (Debian's ``chromium``), as a browser prints it.

Chromium lays the page out with the page's own ``@media print`` rules and A4 ``@page`` size.
The page needs nothing but itself, and the printer is locked down so that, should a value ever
escape the pages' escaping, nothing could come of it: every page carries a Content-Security-Policy
(``default-src 'none'``: no script, no fetch, no frame), and the printer puts :data:`POLICY` first
in the copy it prints whatever the page says, so that scripts never run there (Chromium's own
switch, ``--blink-settings=scriptEnabled=false``, stops its headless printer from printing at all);
no host name resolves (``--host-resolver-rules``), the profile is a throwaway folder, and the
background services that call home are off. Chromium runs in a process group of its own, killed
with everything it started if the command is interrupted (Ctrl-C, SIGTERM) and, through the
parent-death signal, if the command itself is killed. Its temporary folder is removed on every
way out; one left by a killed command is removed by the next print.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import re
import shutil
import signal
import subprocess
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

from station.common.files import atomic_write_bytes, output_set, staged_path
from station.errors import OutputFileError, StationError

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
TIMEOUT_S = 120.0
WORK_PREFIX = "imu-station-pdf-"
# Chromium's flags: print headless, read nothing but the page, reach no host, remember nothing.
LOCKDOWN = ("--headless", "--disable-gpu", "--no-first-run", "--no-default-browser-check",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            "--disable-extensions", "--disable-default-apps", "--disable-domain-reliability",
            "--disable-client-side-phishing-detection", "--no-pings", "--dns-prefetch-disable",
            "--metrics-recording-only", "--disable-breakpad", "--disable-features=Translate,MediaRouter",
            "--host-resolver-rules=MAP * ~NOTFOUND", "--no-pdf-header-footer")
# The pages' own policy (templates/base.html.j2), put first in the copy printed.
POLICY = ("default-src 'none'; style-src 'unsafe-inline'; img-src data:; font-src data:; base-uri 'none'; "
          "form-action 'none'")
_PR_SET_PDEATHSIG = 1


def find_browser() -> str | None:
    """The headless browser that prints the PDF: ``$IMU_STATION_CHROMIUM``, else the first of
    :data:`BROWSERS` on the PATH; None when there is none."""
    given = os.environ.get("IMU_STATION_CHROMIUM")
    if given:
        return shutil.which(given)
    return next((found for name in BROWSERS if (found := shutil.which(name))), None)


def browser_flags(work: Path, out: Path) -> list[str]:
    """Chromium's command-line flags for printing into ``out`` with its profile in ``work``."""
    flags = [*LOCKDOWN, f"--user-data-dir={work / 'profile'}", f"--print-to-pdf={out}"]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        flags.append("--no-sandbox")  # Chromium refuses to start as root with its sandbox
    return flags


T = TypeVar("T")


def write_with_pdf(html_path: str | Path, pdf_path: str | Path | None, write_page: Callable[[], T],
                   on_print: Callable[[], None] | None = None) -> T:
    """Write a report page with ``write_page`` and print it to ``pdf_path`` as one set of files: both
    appear, or (an error, Ctrl-C, SIGTERM) neither changes, so a new page never stands beside an old
    PDF. Without Chromium the page alone is written and :func:`html_to_pdf`'s error (what to install)
    raised.

    Parameters
    ----------
    html_path : str or Path
        The page ``write_page`` writes.
    pdf_path : str or Path, optional
        The PDF; None writes the page alone.
    write_page : callable
        Writes the page (atomically); its result is returned.
    on_print : callable, optional
        Told when printing starts (a progress line).

    Returns
    -------
    object
        What ``write_page`` returned.
    """
    printing = pdf_path is not None and find_browser() is not None
    with output_set():
        result = write_page()
        if printing:
            assert pdf_path is not None
            if on_print is not None:
                on_print()
            html_to_pdf(staged_path(html_path), pdf_path)
    if pdf_path is not None and not printing:
        html_to_pdf(html_path, pdf_path)
    return result


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
    with _work_folder() as work:
        out, page = work / "page.pdf", work / "page.html"
        try:
            page.write_text(with_policy(Path(html_path).read_text(encoding="utf-8")), encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise StationError(f"--pdf {pdf_path}: cannot read the page {html_path}: {exc}") from None
        returncode, stderr = _print(browser, browser_flags(work, out), page, pdf_path)
        if not out.exists() or out.stat().st_size == 0:
            tail = stderr.strip().splitlines()[-3:]
            raise StationError(f"--pdf {pdf_path}: {browser} printed no PDF (exit {returncode}: "
                               f"{' / '.join(tail) or 'no message'}); the HTML {html_path} is written")
        try:
            atomic_write_bytes(pdf_path, out.read_bytes())
        except OSError as exc:
            raise OutputFileError(pdf_path, f"cannot write the PDF: {exc.strerror}") from None


def with_policy(html: str) -> str:
    """``html`` with :data:`POLICY` as the first element of its head (before anything the page says)."""
    meta = f'<meta http-equiv="Content-Security-Policy" content="{POLICY}">'
    head = re.search(r"<head\b[^>]*>", html, re.IGNORECASE)
    if head is None:
        return meta + html
    return html[: head.end()] + meta + html[head.end():]


def _print(browser: str, flags: list[str], html_path: Path, pdf_path: Path) -> tuple[int, str]:
    """Run Chromium on the page; kill its whole process group on any way out but its own end."""
    proc = subprocess.Popen([browser, *flags, html_path.resolve().as_uri()], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_die_with_parent)
    try:
        _, stderr = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise StationError(f"--pdf {pdf_path}: {browser} did not finish printing within {TIMEOUT_S:g} s; "
                           f"the HTML {html_path} is written") from None
    finally:
        # Chromium's helpers (renderer, zygote) outlive the browser process if left alone
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, signal.SIGKILL)
        if proc.returncode is None:
            proc.wait()
    return proc.returncode, stderr


def _die_with_parent() -> None:
    """In the child before Chromium starts: the kernel kills it when the command dies (Linux)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)


@contextlib.contextmanager
def _work_folder() -> Iterator[Path]:
    """A temporary folder named for this process, removed on the way out; folders of commands that
    were killed (their process gone) are removed first."""
    base = Path(tempfile.gettempdir())
    for stale in base.glob(f"{WORK_PREFIX}*-*"):
        pid = stale.name[len(WORK_PREFIX):].split("-", 1)[0]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(stale, ignore_errors=True)
    with tempfile.TemporaryDirectory(prefix=f"{WORK_PREFIX}{os.getpid()}-") as work:
        yield Path(work)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
