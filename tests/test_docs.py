"""The manual and the front door: the MkDocs site builds with --strict and renders in headless Chromium
as a person sees it (headings, images loaded, not a blank page); README.md stays short and names only
files that exist; the command reference is in step with the parsers; nothing points at files a user
never has (../shared)."""

from __future__ import annotations

import argparse
import html
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The manual built with ``mkdocs build --strict`` into a temporary folder."""
    out = tmp_path_factory.mktemp("site")
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stdout}\n{done.stderr}"
    return out


def chromium(absent: Callable[[str], NoReturn] = pytest.fail) -> str:
    """Debian's chromium; where it is not installed, ``absent`` (this test fails, the report tests
    skip) says how to install it."""
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        absent("headless Chromium is not installed (Debian: apt-get install chromium)")
    return path


def _probe(page: Path, profile: Path) -> dict:
    """Open ``page`` in headless Chromium and report, once it has loaded, its headings and images.

    A copy of the page beside it (so its relative links resolve the same) gets a script that writes
    what the browser made of the page into the DOM, which ``--dump-dom`` then prints.
    """
    script = """<script>
window.addEventListener('load', () => {
  const probe = document.createElement('pre');
  probe.id = 'docs-probe';
  probe.textContent = JSON.stringify({
    title: document.title,
    headings: [...document.querySelectorAll('article h1, article h2')]
      .map(h => h.textContent.replace('¶', '').trim()),
    images: [...document.querySelectorAll('article img')].map(i => ({src: i.getAttribute('src'),
      complete: i.complete, width: i.naturalWidth, height: i.naturalHeight})),
    stylesheets: document.styleSheets.length,
    // a command broken across lines in a heading or a table cell ("-" then "-method")
    brokenCode: [...document.querySelectorAll('article h1 code, article h2 code, article td code')]
      .filter(c => c.getClientRects().length > 1).map(c => c.textContent),
    // a code block whose lines run past its box (hidden behind a scroll bar)
    clippedBlocks: [...document.querySelectorAll('article pre > code')]
      .filter(c => c.scrollWidth > c.clientWidth + 1).map(c => c.textContent.slice(0, 60)),
  });
  document.body.appendChild(probe);
});
</script>"""
    copy = page.with_name("docs-probe.html")
    copy.write_text(page.read_text(encoding="utf-8").replace("</body>", script + "</body>"), encoding="utf-8")
    done = subprocess.run([chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                           "--window-size=1280,1600", "--virtual-time-budget=10000", "--dump-dom",
                           copy.as_uri()],
                          capture_output=True, text=True, timeout=120)
    copy.unlink()
    match = re.search(r'<pre id="docs-probe">(.*?)</pre>', done.stdout, re.S)
    assert match, f"Chromium did not load {page}:\n{done.stderr[-2000:]}"
    return json.loads(html.unescape(match.group(1)))


def _screenshot(page: Path, profile: Path, png: Path) -> Image.Image:
    done = subprocess.run([chromium(), *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                           "--window-size=1280,1600", "--virtual-time-budget=10000", f"--screenshot={png}",
                           page.as_uri()],
                          capture_output=True, text=True, timeout=120)
    assert png.exists(), f"Chromium made no screenshot of {page}:\n{done.stderr[-2000:]}"
    return Image.open(png).convert("RGB")


def test_every_page_of_the_navigation_is_built_and_the_api_pages_hold_the_docstrings(site):
    for page in ["index.html", "getting-started/index.html", "guide/demo/index.html",
                 "workflows/thermal/index.html", "reference/commands/index.html",
                 "reference/native-protocol/index.html", "methods/allan/index.html", "changelog/index.html"]:
        assert (site / page).is_file(), f"{page} was not built"
    drivers = (site / "reference/api/drivers/index.html").read_text(encoding="utf-8")
    assert "open_device" in drivers and "doc-function" in drivers, "mkdocstrings rendered nothing for drivers"
    changelog = (site / "changelog/index.html").read_text(encoding="utf-8")
    assert "0.1.0" in changelog and "Unreleased" in changelog, "CHANGELOG.md was not included"


@pytest.mark.parametrize("page, heading, image", [
    ("index.html", "imu-station", "assets/tui-wizard.svg"),
    ("workflows/thermal/index.html", "Temperature compensation", "../../assets/thermal.png"),
])
def test_pages_render_in_chromium_with_their_headings_and_images(site, tmp_path, page, heading, image):
    report = _probe(site / page, tmp_path / "profile")
    assert report["stylesheets"] >= 1, "the theme's stylesheets did not load"
    assert any(heading in h for h in report["headings"]), report["headings"]
    assert len(report["headings"]) >= 2, report["headings"]
    sources = [i["src"] for i in report["images"]]
    assert image in sources, sources
    for img in report["images"]:
        loaded = img["complete"] and img["width"] > 100 and img["height"] > 100
        assert loaded, f"{img['src']} did not load: {img}"
    shot = _screenshot(site / page, tmp_path / "profile", tmp_path / "page.png")
    # A person sees text and a picture, not an empty page: many colours, and dark pixels (text) on the page.
    colours = shot.getcolors(maxcolors=1 << 20)
    assert colours is not None and len(colours) > 200, "the page looks blank"
    dark = sum(n for n, rgb in colours if sum(rgb) < 200)
    assert dark > 2000, "no text drawn on the page"


@pytest.mark.parametrize("page", ["workflows/calibration-turntable/index.html",
                                  "workflows/calibration-handheld/index.html",
                                  "workflows/protocols/index.html", "reference/commands/index.html"])
def test_commands_are_not_broken_or_clipped_at_1280_px(site, tmp_path, page):
    report = _probe(site / page, tmp_path / "profile")
    assert report["brokenCode"] == [], f"code broken across lines: {report['brokenCode']}"
    assert report["clippedBlocks"] == [], f"code blocks clipped: {report['clippedBlocks']}"


def test_tui_pictures_load_no_font_from_the_network():
    for svg in sorted((ROOT / "docs" / "assets").glob("tui-*.svg")):
        text = svg.read_text(encoding="utf-8")
        assert "url(\"http" not in text and "@font-face" not in text, svg.name
        assert "DejaVu Sans Mono" in text and "font-size: 21px" in text, svg.name


def test_readme_is_short_and_names_only_files_that_exist():
    text = README.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250, f"README.md has {len(text.splitlines())} lines (at most 250)"
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    top = {line.split("/")[0] for line in tracked.splitlines()}
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    words = re.findall(r"`([^`]+)`", text) + [w for block in re.findall(r"```console\n(.*?)```", text, re.S)
                                               for w in block.split()]
    named = [w for w in links if "://" not in w and not w.startswith("#")]
    for word in words:
        for token in re.split(r"[\s,;()'\"]+", word):
            path = token.removeprefix("./").rstrip(".:")
            if "/" in path and "://" not in path and path.split("/")[0] in top:
                named.append(path)
    assert named, "the check found no file names in README.md"
    missing = sorted({p for p in named if not (ROOT / p.split("#")[0]).exists()})
    assert not missing, f"README.md names files that do not exist: {missing}"


def _commands_script():
    spec = importlib.util.spec_from_file_location("docs_commands", ROOT / "scripts" / "docs_commands.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_option_row_says_what_it_means_and_actions_have_their_options():
    page = (ROOT / "docs" / "reference" / "commands.md").read_text(encoding="utf-8")
    empty = [line for line in page.splitlines() if re.fullmatch(r"\| `[^`]+` \|\s*\|", line)]
    assert not empty, f"option rows without a meaning: {empty}"
    assert "### `imu-station frame check`" in page and "| `--file RAW` |" in page


def test_command_reference_is_in_step_with_the_parsers(monkeypatch):
    monkeypatch.setenv("COLUMNS", "100")
    module = _commands_script()
    page = module.PAGE.read_text(encoding="utf-8")
    assert page == module.render(), ("docs/reference/commands.md is out of step with the parsers: "
                                     "run python scripts/docs_commands.py")
    from station.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name, parser in sub.choices.items():
        assert f"## `imu-station {name}`" in page
        for action in parser._actions:
            for option in action.option_strings:
                assert f"`{option}" in page, f"imu-station {name} {option} is not in the command reference"


def test_nothing_points_at_files_a_user_never_has():
    pages = [README, ROOT / "CHANGELOG.md", *DOCS.rglob("*.md")]
    offending = [f"{p.relative_to(ROOT)}: {m}" for p in pages
                 for m in re.findall(r"\S*shared/(?:specs|data)\S*", p.read_text(encoding="utf-8"))]
    assert not offending, offending
