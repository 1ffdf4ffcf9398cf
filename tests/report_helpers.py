"""Checks the report tests share: the page is well-formed HTML, holds no network resource, and
Chromium renders it (and its PDF, through pdftoppm) to something that is not blank."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import pytest
from PIL import Image, ImageStat
from test_docs import CHROMIUM_FLAGS
from test_docs import chromium as docs_chromium

REPO = Path(__file__).resolve().parents[1]
VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source", "track", "wbr"}
# SVG elements matplotlib writes self-closed (<path .../>) are closed by the parser's startendtag.


class _Balance(HTMLParser):
    """Every element that is opened is closed, in order (void elements excepted)."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.stack: list[tuple[str, tuple[int, int]]] = []
        self.errors: list[str] = []
        self.refs: list[tuple[str, str, str]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.refs += [(tag, k, v or "") for k, v in attrs if k in ("src", "href", "xlink:href", "data")]
        if tag not in VOID:
            self.stack.append((tag, self.getpos()))

    def handle_startendtag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.refs += [(tag, k, v or "") for k, v in attrs if k in ("src", "href", "xlink:href", "data")]

    def handle_endtag(self, tag: str) -> None:
        if tag in VOID:
            return
        if not self.stack or self.stack[-1][0] != tag:
            opened = self.stack[-1] if self.stack else "nothing"
            self.errors.append(f"line {self.getpos()[0]}: </{tag}> closes {opened}")
            return
        self.stack.pop()


def check_page(path: Path) -> str:
    """Assert the page is balanced HTML5 that loads nothing from anywhere; return its text."""
    text = path.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>")
    parser = _Balance()
    parser.feed(text)
    parser.close()
    assert not parser.errors, parser.errors[:5]
    assert not parser.stack, f"unclosed: {parser.stack[:5]}"
    # No resource from anywhere: no http(s) at all (SVG namespace declarations aside), no <link>,
    # <script> or <img>; links only to local files or anchors within the page.
    stripped = re.sub(r'xmlns(:\w+)?="http://www\.w3\.org/[^"]*"', "", text)
    assert "http://" not in stripped and "https://" not in stripped
    assert not re.search(r"<(link|script|img|iframe|object)\b", text)
    for tag, attr, value in parser.refs:
        if value.startswith(("#", "data:")):  # within the page (SVG markers, anchors) or inline data
            continue
        assert tag == "a" and attr == "href", f"<{tag} {attr}={value!r}> loads a resource"
        assert not re.match(r"^[a-z]+:", value) or value.startswith("file:"), value
    return text


def chromium() -> str:
    """Debian's chromium; the test is skipped, saying why, where it is not installed."""
    return docs_chromium(pytest.skip)


def not_blank(png: Path) -> None:
    """The image has ink: a spread of grey levels and enough non-white pixels."""
    image = Image.open(png).convert("L")
    stat = ImageStat.Stat(image)
    assert stat.stddev[0] > 10.0, f"{png} looks blank (grey stddev {stat.stddev[0]:.1f})"
    dark = sum(image.histogram()[:200])
    assert dark > 0.01 * image.width * image.height, f"{png}: almost no ink"


def screenshot(page: Path, tmp_path: Path) -> Path:
    """Chromium's screenshot of the page (1200 x 1600)."""
    png = tmp_path / f"{page.stem}.png"
    done = subprocess.run([chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}",
                           "--window-size=1200,1600", "--virtual-time-budget=5000", f"--screenshot={png}",
                           page.as_uri()], capture_output=True, text=True, timeout=120)
    assert png.exists(), done.stderr[-2000:]
    return png


def pdf_pages(pdf: Path, tmp_path: Path) -> list[Path]:
    """The PDF's pages as PNG (pdftoppm, 50 dpi); skipped where poppler-utils is not installed."""
    tool = shutil.which("pdftoppm")
    if tool is None:
        pytest.skip("pdftoppm is not installed (Debian: apt-get install poppler-utils)")
    assert pdf.read_bytes().startswith(b"%PDF-")
    subprocess.run([tool, "-r", "50", "-png", str(pdf), str(tmp_path / "page")], check=True, timeout=120)
    return sorted(tmp_path.glob("page*.png"))


def cli(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``imu-station ARGS`` in its own process."""
    full = {**os.environ, "COLUMNS": "160", **(env or {})}
    full.pop("IMU_STATION_DB", None)
    return subprocess.run([sys.executable, "-m", "station.cli", *args], cwd=cwd, env=full,
                          capture_output=True, text=True, timeout=280)
