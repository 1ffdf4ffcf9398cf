"""The campaign section of a plan, the campaign's steps, its journal and its bias hysteresis figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from station.errors import InputFileError
from station.factory.campaign import campaign_steps
from station.factory.campaign_figures import Sweep, bias_hysteresis
from station.factory.journal import TORN, Journal, JournalError, file_entry
from station.factory.plan import load_plan

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "campaign.yaml"

HEAD = """schema: imu-station/plan/1
name: c
sequence: six-position
instruments:
  chamber: {url: "votsch://h", min_c: -40, max_c: 85, max_gradient: 3}
  supply: {url: "scpi://h", max_v: 12, max_a: 1}
"""


def _plan(tmp_path: Path, campaign: str, head: str = HEAD) -> Path:
    path = tmp_path / "plan.yaml"
    path.write_text(head + "campaign:\n" + campaign)
    return path


def test_example_campaign_reads_as_documented() -> None:
    plan = load_plan(EXAMPLE)
    c = plan.campaign
    assert c is not None
    assert c.soaks_c == (-20.0, 0.0, 20.0, 40.0, 60.0)
    assert c.ramp_c_per_min <= plan.instruments.limits.max_gradient  # type: ignore[union-attr,operator]
    assert (c.power_cycles, c.sequence, c.ramp_record) == (3, True, True)
    assert plan.sequence.name.startswith("twelve") and len(plan.sequence) == 18  # twelve poses, six turns


def test_campaign_steps_in_order() -> None:
    c = load_plan(EXAMPLE).campaign
    assert c is not None
    steps = campaign_steps(c)
    ids = [s.id for s in steps]
    per_soak = 1 + 1 + c.power_cycles + 1  # ramp, sequence, turn-ons, still
    assert len(ids) == len(set(ids)) == per_soak * len(c.soaks_c) + 1
    assert ids[:6] == ["ramp-1", "soak-1.sequence", "soak-1.turn-on-1", "soak-1.turn-on-2",
                       "soak-1.turn-on-3", "soak-1.still"]
    assert ids[-1] == "ramp-end" and steps[-1].temp_c == c.end_c
    assert [s.temp_c for s in steps if s.kind == "ramp"][:-1] == list(c.soaks_c)


@pytest.mark.parametrize(("campaign", "line", "column", "words"), [
    ("  soaks_c: [20, 90]\n  ramp_c_per_min: 2\n", 8, "soaks_c", "beyond the chamber's limits"),
    ("  soaks_c: [20, 30]\n  ramp_c_per_min: 4\n", 9, "ramp_c_per_min", "max_gradient"),
    ("  soaks_c: 20\n  ramp_c_per_min: 2\n", 8, "soaks_c", "list of temperatures"),
    ("  soaks_c: [20, 20]\n  ramp_c_per_min: 2\n", 8, "soaks_c", "twice in a row"),
    ("  soaks_c: [20, 30]\n", 8, "ramp_c_per_min", "no 'ramp_c_per_min'"),
    ("  soaks_c: [20, 30]\n  ramp_c_per_min: 2\n  soak: {power_cycles: 2}\n", 10, "power_cycles",
     "at least 3"),
    ("  soaks_c: [20, 30]\n  ramp_c_per_min: 2\n  soak: {still_s: -1}\n", 10, "still_s", "positive"),
    ("  soaks_c: [20, 30]\n  ramp_c_per_min: 2\n  settle: {hold: 3}\n", 10, "hold", "unknown key"),
    ("  soaks_c: [20, 30]\n  ramp_c_per_min: 2\n  simulate: {speed: 500}\n", 10, "speed", "above"),
    ("  soaks_c: [20, 30]\n  ramp_c_per_min: 2\n  end_c: -60\n", 10, "end_c", "beyond"),
    ("  soaks_c: [20, 30]\n  ramp_c_per_min: 2\n  ramp: {rate_hz: 0}\n", 10, "rate_hz", "whole number"),
])
def test_bad_campaign_names_line_and_field(tmp_path: Path, campaign: str, line: int, column: str,
                                           words: str) -> None:
    with pytest.raises(InputFileError) as info:
        load_plan(_plan(tmp_path, campaign))
    assert (info.value.line, info.value.column) == (line, column)
    assert words in info.value.problem and str(tmp_path / "plan.yaml") in str(info.value)


def test_campaign_needs_chamber_and_supply(tmp_path: Path) -> None:
    no_chamber = HEAD.replace('  chamber: {url: "votsch://h", min_c: -40, max_c: 85, max_gradient: 3}\n', "")
    with pytest.raises(InputFileError, match="needs the chamber"):
        load_plan(_plan(tmp_path, "  soaks_c: [20, 30]\n  ramp_c_per_min: 2\n", no_chamber))
    no_supply = HEAD.replace('  supply: {url: "scpi://h", max_v: 12, max_a: 1}\n', "")
    with pytest.raises(InputFileError, match="needs the unit's supply") as info:
        load_plan(_plan(tmp_path, "  soaks_c: [20, 30]\n  ramp_c_per_min: 2\n  soak: {power_cycles: 3}\n",
                        no_supply))
    assert info.value.line == 9


def test_plan_without_campaign_unchanged(tmp_path: Path) -> None:
    plan = load_plan(Path(__file__).resolve().parent.parent / "examples" / "plan.yaml")
    assert plan.campaign is None


# ---- the journal --------------------------------------------------------------------------------------


def test_journal_appends_lines_and_refuses_a_step_twice(tmp_path: Path) -> None:
    journal = Journal.create(tmp_path, {"run_id": "r"})
    capture = tmp_path / "ramp-1.csv"
    capture.write_text("t\n1\n")
    journal.append({"type": "step", "step": "ramp-1", "files": [file_entry(tmp_path, capture)]})
    with pytest.raises(JournalError, match="journaled already"):
        journal.append({"type": "step", "step": "ramp-1"})
    journal.close()
    lines = [json.loads(line) for line in (tmp_path / "journal.jsonl").read_text().splitlines()]
    assert [e["seq"] for e in lines] == [0, 1] and lines[1]["files"][0]["size"] == capture.stat().st_size
    again = Journal.open(tmp_path)
    assert list(again.steps()) == ["ramp-1"] and again.verify() == []
    capture.write_text("t\n2\n")
    assert again.verify() and "changed since step ramp-1" in again.verify()[0]
    capture.unlink()
    assert "missing" in again.verify()[0]
    again.close()


def test_journal_cuts_a_torn_last_line_and_keeps_it(tmp_path: Path) -> None:
    Journal.create(tmp_path, {"run_id": "r"}).close()
    path = tmp_path / "journal.jsonl"
    whole = path.read_bytes()
    with open(path, "ab") as f:
        f.write(b'{"seq": 1, "type": "step", "step": "ra')  # a power cut in the middle of the write
    journal = Journal.open(tmp_path)
    assert len(journal.entries) == 1 and path.read_bytes() == whole
    assert (tmp_path / TORN).read_bytes().startswith(b'{"seq": 1')
    journal.append({"type": "step", "step": "ramp-1"})
    journal.close()
    assert [json.loads(x)["seq"] for x in path.read_text().splitlines()] == [0, 1]


def test_journal_refuses_edited_lines_and_an_ended_run(tmp_path: Path) -> None:
    with pytest.raises(JournalError, match="no journal.jsonl"):
        Journal.open(tmp_path)
    journal = Journal.create(tmp_path, {"run_id": "r"})
    journal.append({"type": "end", "outcome": "PASS", "record": "record.json"})
    journal.close()
    with pytest.raises(JournalError, match="the run ended"):
        Journal.open(tmp_path)
    path = tmp_path / "journal.jsonl"
    path.write_text(path.read_text().replace('"seq": 1', '"seq": 7'))
    with pytest.raises(InputFileError) as info:
        Journal.open(tmp_path)
    assert info.value.line == 2
    with pytest.raises(JournalError, match="exists"):
        Journal.create(tmp_path, {})


# ---- bias hysteresis ------------------------------------------------------------------------------------


def test_hysteresis_recovers_an_injected_offset() -> None:
    """Truth: the down sweep reads h lower than the up sweep at every temperature, over a common curve."""
    rng = np.random.default_rng(4)
    h_acc, h_gyro = np.array([0.01, -0.02, 0.005]), np.array([1e-4, 0.0, -3e-4])

    def sweep(direction: int, t0: float, t1: float) -> Sweep:
        temp = np.linspace(t0, t1, 4000)
        base = np.stack([0.001 * temp, -0.002 * temp, 9.8 + 1e-4 * temp ** 2], axis=1)
        shift = 0.5 * (1 if direction > 0 else -1)
        acc = base + shift * h_acc + rng.normal(0, 1e-3, base.shape)
        gyro = 1e-5 * base + shift * h_gyro + rng.normal(0, 1e-5, base.shape)
        return Sweep(direction, temp, acc, gyro)

    up, down, first = sweep(1, -20, 60), sweep(-1, 60, 25), sweep(-1, 23, -20)
    result = bias_hysteresis([up, down, first])
    assert result is not None
    np.testing.assert_allclose(result.accel, h_acc, atol=2e-4)  # noise 1e-3 over ~100 samples per bin
    np.testing.assert_allclose(result.gyro, h_gyro, atol=2e-6)
    assert -20 <= result.t_min < -19 and 59 < result.t_max <= 61
    # An independent reference: means over the common range by plain masks, bin by bin.
    edges = np.arange(-20.0, 61.0, 1.0)
    down_all = [down, first]
    diffs = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m_up = (up.temp >= lo) & (up.temp < hi)
        d_t = np.concatenate([d.temp for d in down_all])
        d_a = np.concatenate([d.acc for d in down_all])
        m_dn = (d_t >= lo) & (d_t < hi)
        if m_up.sum() >= 20 and m_dn.sum() >= 20:
            diffs.append(up.acc[m_up].mean(axis=0) - d_a[m_dn].mean(axis=0))
    assert len(diffs) == result.bins
    np.testing.assert_allclose(result.accel, np.mean(diffs, axis=0), rtol=1e-9, atol=1e-12)


def test_hysteresis_needs_both_directions() -> None:
    temp = np.linspace(0, 10, 500)
    one = Sweep(1, temp, np.zeros((500, 3)), np.zeros((500, 3)))
    assert bias_hysteresis([one]) is None
    far = Sweep(-1, temp + 100, np.zeros((500, 3)), np.zeros((500, 3)))
    assert bias_hysteresis([one, far]) is None
