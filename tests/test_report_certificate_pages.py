"""The certificate as printed pages (issue 31): the tour's unit (every section: accel, gyro with its
g-sensitivity, mag with alignment and dip, noise with Gauss-Markov terms, thermal, characterisation) on at
most four A4 pages; every page names the serial, "page N of M" and the revision; no page is near-empty
(measured from the ink of pdftoppm's image); no table cell wraps (each row's cells on one line of
``pdftotext -layout``); one number format; the sections, reference equipment, conditions and approval
block are there; pose labels and Allan legends do not overlap anything."""

from __future__ import annotations

import re
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import yaml
from export_params import make_params
from PIL import Image
from report_helpers import check_page, chromium, cli, pdf_pages
from test_report_certificate import six_pose_capture, still_capture, thermal_sweep

from station.acquisition.capture_csv import write_csv
from station.common.files import sha256_file
from station.factory.records import Attachment, Measurement, Phase, RunRecord
from station.plots.certificate import allan_figure, residuals_figure
from station.report.certificate import Certificate, certificate_context
from station.report.html import css_string, measured, number

MAX_PAGES = 4
CONTENT = (0.045, 0.955)  # the page between the @page margin boxes (12 mm top, 11 mm bottom of 297 mm)


def tour_params(tmp: Path) -> tuple[Path, list[Path]]:
    """The tour's unit: a parameter file with every section the station writes, each section naming the
    capture it came from by SHA-256 (as the tour's commands do), and those captures."""
    params = make_params(1, mag="accel", g_sensitivity=True, noise=True,
                         device={"serial": "SIM-000001", "model": "imu-sim-mems", "firmware": "1.0.0"})
    assert params.accel is not None and params.gyro is not None and params.thermal is not None
    paths = {"pose": tmp / "sequence.csv", "still": tmp / "still.csv", "sweep": tmp / "sweep.csv"}
    write_csv(paths["pose"], six_pose_capture(params.accel, params.gyro, with_mag=True))
    write_csv(paths["still"], still_capture())
    write_csv(paths["sweep"], thermal_sweep(params.thermal))
    source = {k: {"capture": str(p), "sha256": sha256_file(p)} for k, p in paths.items()}
    doc = params.to_dict()
    doc["mag"].update({"coverage": 0.31, "dip_deg": 60.0, "alignment_deg": 1.874,
                       "field_source": "WMM 2025 at 45.07 N 7.68 E, 240 m",
                       "stddev": {"bias": [0.01, 0.01, 0.03], "dip_deg": 0.0097,
                                  "alignment_deg": [0.011, 0.01, 0.025]}})
    for sensor in ("accel", "gyro"):
        part = doc["noise"][sensor]
        part["stddev"] = {t: [v * 0.03 for v in part[t]] if part[t] else None for t in part if len(t) == 1}
        part["GM"] = [[[6e-4, 142.0]], [[5e-4, 142.0]], [[5e-4, 94.8]]]
        part["valid_tau"] = [[0.005, 1581.0]] * 3
    doc["noise"]["record"] = {"tau_range_s": [0.01, 300.0]}
    doc["characterisation"] = {"turn_ons": 10, "accel_bias_repeatability": [1e-3, 2e-3, 1.5e-3],
                               "gyro_bias_repeatability": [1e-4, 2e-4, None]}
    doc["sources"] = {"accel": source["pose"], "gyro": source["pose"], "mag": source["pose"],
                      "noise": source["still"], "thermal": source["sweep"]}
    path = tmp / "unit.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path, list(paths.values())


class _Rows(HTMLParser):
    """The text of every cell of every ``table.grid`` row, row by row."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.rows: list[list[str]] = []
        self._depth = 0
        self._cell: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        if tag == "table":
            self._depth += 1 if "grid" in (dict(attrs).get("class") or "") or self._depth else 0
        elif tag == "tr" and self._depth:
            self.rows.append([])
        elif tag in ("td", "th") and self._depth:
            self._cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag == "table" and self._depth:
            self._depth -= 1
        elif tag in ("td", "th") and self._cell is not None:
            self.rows[-1].append(" ".join("".join(self._cell).split()))
            self._cell = None

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)


def _fill(png: Path) -> float:
    """How far down the page's content area the ink reaches (0: nothing below the header, 1: the footer)."""
    image = np.asarray(Image.open(png).convert("L"))
    top, bottom = (int(f * image.shape[0]) for f in CONTENT)
    inked = np.nonzero((image[top:bottom] < 200).sum(axis=1) > 2)[0]
    return 0.0 if inked.size == 0 else float(inked[-1]) / (bottom - top)


@pytest.fixture(scope="module")
def printed(tmp_path_factory: pytest.TempPathFactory) -> dict:
    chromium()
    tmp = tmp_path_factory.mktemp("tour")
    params, captures = tour_params(tmp)
    args = ["report", str(params)]
    for c in captures:
        args += ["--capture", str(c)]
    done = cli(*args, "--operator", "J. Smith", "-o", "unit.html", "--pdf", "unit.pdf", cwd=tmp)
    assert done.returncode == 0, done.stderr
    pdf = tmp / "unit.pdf"
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], capture_output=True, text=True,
                          check=True, timeout=60).stdout
    return {"tmp": tmp, "html": check_page(tmp / "unit.html"), "pages": text.split("\f")[:-1],
            "png": pdf_pages(pdf, tmp), "stderr": done.stderr, "params": params}


def test_the_tours_unit_prints_on_few_pages_each_naming_serial_page_and_revision(printed: dict) -> None:
    pages = printed["pages"]
    assert 1 < len(pages) <= MAX_PAGES, len(pages)
    assert len(printed["png"]) == len(pages)
    revision = sha256_file(printed["params"])[:12]
    for n, page in enumerate(pages, 1):
        assert "SIM-000001" in page, n
        assert f"page {n} of {len(pages)}" in page, n
        assert f"revision {revision}" in page, n


def test_no_page_is_near_empty(printed: dict) -> None:
    fills = [_fill(p) for p in printed["png"]]
    # A figure or a table row never splits, so a page may end early by the height of the next figure
    # (about a quarter page); the old page 5 was 80 % blank: its content stopped 20 % down.
    for n, fill in enumerate(fills[:-1], 1):
        assert fill > 0.6, f"page {n} of {len(fills)}: content ends {fill:.0%} down the page"
    assert fills[-1] > 0.2, f"the last page holds almost nothing ({fills[-1]:.0%})"


def test_no_table_cell_wraps(printed: dict) -> None:
    """Every row of every parameter, datasheet, equipment and measurement table has all its cells on one
    line of the printed text: a wrapped cell (the datasheet's old "measured by") splits its row."""
    rows = _Rows()
    rows.feed(printed["html"])
    lines = "\n".join(printed["pages"]).splitlines()
    checked = 0
    for cells in rows.rows:
        cells = [c for c in cells if c]
        if len(cells) < 2:
            continue
        pattern = re.compile(r"[ \t]+".join(r"[ \t]*".join(map(re.escape, c.split())) for c in cells))
        assert any(pattern.search(line) for line in lines), f"row wraps or is missing: {cells}"
        checked += 1
    assert checked > 60  # the grid tables were found


def test_every_section_in_readable_units_and_one_number_format(printed: dict) -> None:
    text = printed["html"]
    for needed in ("soft iron (matrix), row x", "dip (inclination)", "60.0000 \u00b1 0.0097", "1.874",
                   "alignment to the accelerometer", "WMM 2025 at 45.07 N", "g-sensitivity, row x", "deg/s/g",
                   "thermal bias coefficients", "t\u00b3", "mg/\u00b0C", "Gauss-Markov 1 sigma",
                   "Gauss-Markov 1 tau_c", "model valid to", "gyroscope_noise_density",
                   "accelerometer_random_walk", "dT clamp", "turn-on bias repeatability",
                   "the field directions cover 31% of the sphere", "approved by (quality)", "checked by",
                   "J. Smith", "6 static poses (+x, -x, +y, -y, +z, -z)"):
        assert needed in text, needed
    assert "note: to 60.0" not in text and "value -10" not in text  # the range reads as a range
    assert re.search(r'calibrated range</td><td class="u">degC</td><td class="c" colspan="3">-10.0 to 60.0',
                     text)
    # no exponent for a figure people read (the old 2.107e+04 ppm), and the same figure reads the same in
    # the parameter table and the datasheet
    assert not re.search(r"\de\+0[0-6]\b", text)
    rows = _Rows()
    rows.feed(text)
    gyro_scale = next(r for r in rows.rows if r[:2] == ["gyro scale-factor error", "ppm"])
    scale_rows = [r for r in rows.rows if r[:2] == ["scale error", "ppm"]]
    assert gyro_scale[2:5] == scale_rows[1][2:5]  # the gyroscope's table comes second
    assert "the field directions cover 31%" in printed["stderr"]  # the terminal repeats the warning


def test_reference_equipment_and_conditions(printed: dict, tmp_path: Path) -> None:
    text = printed["html"]
    assert "reference magnetic field" in text and "48.5 uT from WMM 2025 at 45.07 N" in text
    assert "unit temperature during the thermal capture" in text
    assert "air temperature, humidity, pressure" in text
    # a factory run's instruments, with the identity each answered
    record = RunRecord("U-1", "line-a-1", {"name": "p", "sha256": "0" * 64, "sequence": "six-position"},
                       files_dir=str(tmp_path))
    record.phases.append(Phase("instruments", measurements=[
        Measurement("instrument.chamber", "ACME CH-40 s/n 1234 fw 2.1", doc="tcp://10.0.0.5:5025"),
        Measurement("instrument.table", "TURN-1 s/n 77", doc="serial:///dev/ttyS1")]))
    record.phases.append(Phase("soak", measurements=[Measurement("chamber.soak_c", 25.0, "degC")]))
    context = certificate_context(Certificate(None, record=record))
    shown = {(e.what, e.identity, e.where) for e in context["equipment"]}
    assert ("climatic chamber", "ACME CH-40 s/n 1234 fw 2.1", "tcp://10.0.0.5:5025") in shown
    assert ("rate table", "TURN-1 s/n 77", "serial:///dev/ttyS1") in shown
    assert {"what": "chamber.soak_c", "value": "25 degC", "source": "factory record"} in context["ambient"]
    assert context["station"] == "line-a-1" and context["sequence"] == "six-position"
    # the identities from instruments.json when the record has no instrument measurements
    (tmp_path / "instruments.json").write_text('{"instruments": {"supply": {"identity": "PSU-3"}}}')
    attached = Attachment("instruments", "instruments.json", "0" * 64, 1)
    record.phases[0] = Phase("instruments", attachments=[attached])
    shown = {(e.what, e.identity) for e in certificate_context(Certificate(None, record=record))["equipment"]}
    assert ("power supply", "PSU-3") in shown
    # a plan's instruments are named, not identified
    context = certificate_context(Certificate(None, record=None, plan={"instruments": {"table": "tcp://t:1"}}))
    assert [(e.what, e.identity) for e in context["equipment"]] == [("rate table", "named by the plan, "
                                                                                    "not identified")]


def test_pose_labels_and_allan_legends_overlap_nothing() -> None:
    poses = ["+x", "-x", "+y", "-y", "+z", "-z", "+x+y", "-x-y", "+y+z", "-y-z", "+z+x", "-z-x"]
    fig = residuals_figure([{"pose": p, "accel_mg": np.ones(3), "gyro_dph": np.ones(3)} for p in poses])
    fig.draw_without_rendering()
    for ax in fig.axes:
        labels = ax.get_xticklabels()
        assert min(t.get_fontsize() for t in labels) >= 7
        # neighbours turned by theta are parallel lines dx apart along x: dx sin(theta) apart across them,
        # which must exceed the text's height; unturned, their boxes must not meet
        theta = np.radians(labels[0].get_rotation())
        height = labels[0].get_fontsize() * fig.dpi / 72.0
        boxes = [t.get_window_extent() for t in labels]
        for a, b in zip(boxes, boxes[1:], strict=False):
            if theta:
                assert (b.x1 - a.x1) * np.sin(theta) > 1.2 * height, "pose labels run together"
            else:
                assert not a.overlaps(b), "pose labels run together"
    terms = {"N": [1e-3] * 3, "K": [1e-5] * 3, "B": [3e-5] * 3, "Q": None, "R": None}
    fig = allan_figure({"gyro": dict(terms), "accel": dict(terms), "record": {"tau_range_s": [0.01, 1e3]}})
    fig.draw_without_rendering()
    for ax in fig.axes:
        legend = ax.get_legend()
        assert min(t.get_fontsize() for t in legend.get_texts()) >= 7  # 7 pt: drawn at the page's width
        assert not legend.get_window_extent().overlaps(ax.get_window_extent()), "a legend covers the curves"


def test_one_number_rule_and_css_strings() -> None:
    assert [number(v) for v in (21070.4, 0.0123456, -80.0, 1.5e-5, 2.5e7, None)] == [
        "21070", "0.01235", "-80", "1.5e-05", "2.5e+07", "\u2013"]
    assert measured(19054.3, 34.6) == ("19054", "35") and measured(0.22475, 0.0612) == ("0.225", "0.061")
    hostile = 'A"};</style><script>x</script>\\'
    escaped = str(css_string(hostile))
    assert escaped.startswith('"') and escaped.endswith('"') and '"' not in escaped[1:-1]
    assert not set("<>;{}\\") & set(escaped.replace("\\0000", "")[1:-1].replace("\\", ""))


def test_a_hostile_serial_prints_literally_on_every_page(tmp_path: Path) -> None:
    chromium()
    serial = 'Q"7};</style>\\'
    params = make_params(2, device={"serial": serial, "model": "m", "firmware": "1"})
    params.save(tmp_path / "q.yaml")
    done = cli("report", "q.yaml", "--station", "bench-9", "-o", "q.html", "--pdf", "q.pdf", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    check_page(tmp_path / "q.html")
    text = subprocess.run(["pdftotext", "-layout", str(tmp_path / "q.pdf"), "-"], capture_output=True,
                          text=True, check=True, timeout=60).stdout
    pages = text.split("\f")[:-1]
    for n, page in enumerate(pages, 1):
        assert f"serial {serial} \u00b7 page {n} of {len(pages)}" in page
    assert "bench-9" in text
