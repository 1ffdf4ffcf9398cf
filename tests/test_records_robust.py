"""The record database under attack (issue 32): a run's outcome never depends on the database being
writable (its record kept pending, then stored by 'records sync' or the next run); readers take no
write lock and wait a bounded time; damaged, foreign and non-database files, hostile rows and
hostile attachment paths are refused in one line; data never reaches the terminal as markup.

Real SQLite throughout: a database made read-only by a read-only bind mount of its file (root too
cannot write it), locks held by a second connection, FIFOs and symbolic links on disk."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_factory_records import make_record

from station import cli
from station.errors import ExitCode
from station.factory.many import UnitProgress, UnitSpec, summary_table
from station.factory.records import Attachment, RecordStore, RunRecord

REPO = Path(__file__).resolve().parents[1]
PENDING_DIR = "pending-records"  # station.factory.spool.PENDING_DIR
PLAN = """\
schema: imu-station/plan/1
name: quick
sequence: {name: six-position, rotations: false, hold_s: 1}
device: {rate_hz: 100}
run: {timeout_s: 120, step_timeout_s: 20}
limits:
  accel.bias: {max_abs: 80, unit: mg}
"""
SERIAL_OPTIONS = ("--simulate", "--speed", "20", "--serial")


def _env(**extra: str) -> dict[str, str]:
    env = {**os.environ, "IMU_STATION_ID": "test-station", "COLUMNS": "160", **extra}
    env.pop("IMU_STATION_DB", None)
    return env


def _cli(*args: str, cwd: Path, prefix: tuple[str, ...] = (), timeout: float = 120,
         **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*prefix, sys.executable, "-m", "station.cli", *args], cwd=cwd, env=_env(**env),
                          capture_output=True, text=True, timeout=timeout)


def _store(db: Path, tmp: Path, n: int = 3) -> list[RunRecord]:
    records = [make_record(f"A{i}", f"2026-11-2{i}T08:00:00.000000Z", tmp / f"files-{i}") for i in range(n)]
    with RecordStore.open(db) as store:
        for r in records:
            store.save(r)
    return records


def _main(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = cli.main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def writer_lock(tmp_path: Path) -> Iterator[tuple[Path, sqlite3.Connection]]:
    """A records database with three records and a second connection holding its write lock."""
    db = tmp_path / "r.sqlite"
    _store(db, tmp_path)
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("BEGIN IMMEDIATE")
    holder.execute("DELETE FROM meta WHERE key = 'nothing'")
    try:
        yield db, holder
    finally:
        holder.execute("ROLLBACK")
        holder.close()


# --- 1. a run's outcome and record never depend on the database being writable -------------------


def _read_only_prefix(db: Path) -> tuple[str, ...]:
    """A command prefix under which ``db`` is a read-only file, for root as well: a read-only bind
    mount of the file in a private mount namespace (its folder stays writable, as on a line where
    the file alone was made read-only)."""
    if os.geteuid() != 0:
        db.chmod(0o444)
        return ()
    if shutil.which("unshare") is None or subprocess.run(["unshare", "-m", "true"]).returncode != 0:
        pytest.skip("root without unshare -m: no way to make a file read-only for root")
    script = f'mount --bind "{db}" "{db}" && mount -o remount,ro,bind "{db}" && exec "$@"'
    return ("unshare", "-m", "sh", "-c", script, "sh")


def test_a_pass_on_a_read_only_database_exits_0_and_sync_stores_its_record(tmp_path: Path) -> None:
    (tmp_path / "plan.yaml").write_text(PLAN)
    db = tmp_path / "r.sqlite"
    _store(db, tmp_path, 1)
    done = _cli("run", "--plan", "plan.yaml", *SERIAL_OPTIONS, "SIM-RO", "--db", str(db), cwd=tmp_path,
                prefix=_read_only_prefix(db))
    assert done.returncode == ExitCode.OK, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    lines = [line for line in done.stderr.splitlines() if "PENDING" in line]
    assert len(lines) == 1 and "read-only" in lines[0] and "records sync" in lines[0], done.stderr[-2000:]
    pending = list((tmp_path / "r-files" / PENDING_DIR).glob("*.json"))
    assert len(pending) == 1
    db.chmod(0o644)
    synced = _cli("records", "sync", "--db", str(db), cwd=tmp_path)
    assert synced.returncode == 0 and "1 pending record(s) stored" in synced.stdout, synced.stderr
    with RecordStore.open(db, readonly=True) as store:
        assert [r.outcome for r in store.query(serial="SIM-RO")] == ["PASS"]
    assert not list((tmp_path / "r-files" / PENDING_DIR).glob("*.json"))


def test_a_run_on_a_locked_database_keeps_its_record_and_the_next_run_stores_it(
        writer_lock: tuple[Path, sqlite3.Connection]) -> None:
    db, holder = writer_lock
    work = db.parent
    (work / "plan.yaml").write_text(PLAN)
    start = time.monotonic()
    done = _cli("run", "--plan", "plan.yaml", *SERIAL_OPTIONS, "SIM-L1", "--db", str(db), "--json", cwd=work,
                IMU_STATION_DB_WAIT="1")
    assert done.returncode == ExitCode.OK and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert time.monotonic() - start < 25  # a wait of 1 s, not 30
    assert json.loads(done.stdout)["outcome"] == "PASS"
    pending_lines = [line for line in done.stderr.splitlines() if "PENDING" in line]
    assert len(pending_lines) == 1 and "locked" in pending_lines[0], done.stderr[-2000:]
    holder.execute("ROLLBACK")
    holder.execute("BEGIN")  # the fixture's rollback finds a transaction to end
    following = _cli("run", "--plan", "plan.yaml", *SERIAL_OPTIONS, "SIM-L2", "--db", str(db), cwd=work)
    assert following.returncode == ExitCode.OK and "PENDING" not in following.stderr, following.stderr[-2000:]
    with RecordStore.open(db, readonly=True) as store:
        assert {r.serial for r in store.query()} >= {"SIM-L1", "SIM-L2"}
    assert not list((work / "r-files" / PENDING_DIR).glob("*.json"))


def test_sync_refuses_a_bad_pending_file_in_one_line_and_stores_the_others(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = tmp_path / "r.sqlite"
    _store(db, tmp_path, 1)
    folder = tmp_path / "r-files" / PENDING_DIR
    folder.mkdir(parents=True)
    good = make_record("P1", "2026-11-25T08:00:00.000000Z", tmp_path / "p1")
    (folder / f"{good.run_id}.json").write_text(json.dumps(good.to_dict()))
    (folder / "broken.json").write_text('{"schema": "imu-station/record/1", "serial": ')
    os.mkfifo(folder / "fifo.json")
    code, out, err = _main(capsys, "records", "sync", "--db", str(db))
    assert code == ExitCode.USAGE and "Traceback" not in err
    assert [line for line in err.splitlines() if line] == [
        line for line in err.splitlines() if "broken.json" in line or "fifo.json" in line]
    assert len(err.splitlines()) == 2 and "1 pending record(s) stored" in out
    with RecordStore.open(db, readonly=True) as store:
        assert [r.serial for r in store.query(serial="P1")] == ["P1"]


# --- readers: no write lock, a bounded wait ------------------------------------------------------


def test_readers_take_no_write_lock(writer_lock: tuple[Path, sqlite3.Connection], tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    db, _ = writer_lock
    for args in (["records"], ["records", "--verify"], ["records", "report", "--json"],
                 ["report", "--serial", "A1", "-o", str(tmp_path / "cert.html")]):
        start = time.monotonic()
        code, out, err = _main(capsys, *args, "--db", str(db))
        assert code == ExitCode.OK, (args, err)
        assert time.monotonic() - start < 4.0, args  # no wait for the writer at all


def test_a_reader_waits_a_bounded_time_then_says_locked(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    db = tmp_path / "r.sqlite"
    _store(db, tmp_path)
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("PRAGMA journal_mode=DELETE")  # a rollback journal: a writer's lock stops readers
    holder.execute("BEGIN EXCLUSIVE")
    holder.execute("DELETE FROM meta WHERE key = 'nothing'")
    monkeypatch.setenv("IMU_STATION_DB_WAIT", "0.5")
    try:
        for args in (["records"], ["records", "report", "--json"]):
            start = time.monotonic()
            code, _, err = _main(capsys, *args, "--db", str(db))
            assert time.monotonic() - start < 10.0, args
            lines = err.strip().splitlines()
            assert code == ExitCode.USAGE and len(lines) == 1, (args, err)
            assert "locked" in lines[0] and "waited 0.5 s" in lines[0] and str(db) in lines[0]
    finally:
        holder.execute("ROLLBACK")
        holder.close()


# --- 5. damaged, foreign and non-database files ----------------------------------------------------


def _damaged(tmp_path: Path) -> Path:
    db = tmp_path / "damaged.sqlite"
    _store(db, tmp_path)
    data = bytearray(db.read_bytes())
    page = int.from_bytes(data[16:18], "big")
    data[page:] = b"\xa5" * (len(data) - page)  # every page after the schema's
    db.write_bytes(bytes(data))
    return db


def _foreign(tmp_path: Path) -> Path:
    db = tmp_path / "foreign.sqlite"
    conn = sqlite3.connect(db)
    conn.execute("CREATE TABLE runs (id INTEGER PRIMARY KEY, name TEXT)")
    conn.execute("INSERT INTO runs (name) VALUES ('not ours')")
    conn.commit()
    conn.close()
    return db


def _text_file(tmp_path: Path) -> Path:
    db = tmp_path / "notes.sqlite"
    db.write_text("these are not records\n" * 100)
    return db


@pytest.mark.parametrize(("make", "words"), [
    (lambda tmp: Path("/dev/null"), "not a file"),
    (_text_file, "damaged or not a database"),
    (_damaged, "damaged or not a database"),
    (_foreign, "another table layout"),
])
def test_a_bad_database_file_is_one_line_naming_it(make: object, words: str, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    db = make(tmp_path)  # type: ignore[operator]
    for args in (["records"], ["records", "--verify"], ["records", "report", "--json"],
                 ["records", "sync", "--files", str(tmp_path / "nothing-here")]):
        if args[-1].endswith("nothing-here"):
            (tmp_path / "nothing-here" / PENDING_DIR).mkdir(parents=True, exist_ok=True)
            (tmp_path / "nothing-here" / PENDING_DIR / "x.json").write_text("{}")
        code, out, err = _main(capsys, *args, "--db", str(db))
        lines = err.strip().splitlines()
        assert code == ExitCode.USAGE and len(lines) == 1, (args, err)
        assert str(db) in lines[0] and words in lines[0], (args, lines)
    if make is _foreign:  # a writer never adds its tables to another program's database
        with pytest.raises(Exception, match="another table layout"):
            RecordStore.open(db)
        names = {r[0] for r in sqlite3.connect(db).execute("SELECT name FROM sqlite_master")}
        assert names == {"runs"}


def test_a_run_refuses_a_database_that_is_not_one_before_touching_the_unit(tmp_path: Path) -> None:
    (tmp_path / "plan.yaml").write_text(PLAN)
    done = _cli("run", "--plan", "plan.yaml", *SERIAL_OPTIONS, "SIM-N", "--db", "/dev/null", cwd=tmp_path,
                IMU_STATION_DB_WAIT="1")
    lines = done.stderr.strip().splitlines()
    assert done.returncode == ExitCode.USAGE and len(lines) == 1 and "/dev/null" in lines[0], done.stderr


# --- 5. hostile rows -----------------------------------------------------------------------------

HOSTILE_ROWS = {
    "bad-not-json": "{this is not json",
    "bad-missing-keys": json.dumps({"schema": "imu-station/record/1", "serial": "X"}),
    "bad-wrong-types": None,  # filled below: phases as text
    "bad-nan": None,  # filled below: a NaN value
    "bad-array": "[1, 2, 3]",
    "bad-number": 42,
}


def _hostile_db(tmp_path: Path) -> Path:
    db = tmp_path / "r.sqlite"
    good = _store(db, tmp_path)
    proto = good[0].to_dict()
    rows = dict(HOSTILE_ROWS)
    rows["bad-wrong-types"] = json.dumps({**proto, "run_id": "bad-wrong-types", "phases": "everything"})
    nan = json.loads(json.dumps(proto))
    nan["run_id"] = "bad-nan"
    nan["phases"][1]["measurements"][0]["value"] = "NaN-placeholder"
    rows["bad-nan"] = json.dumps(nan).replace('"NaN-placeholder"', "NaN")
    conn = sqlite3.connect(db)
    for i, (run_id, text) in enumerate(rows.items()):
        conn.execute("INSERT INTO runs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                     (run_id, "EVIL", "st-1", "p", "", f"2026-11-23T0{i}:00:00.000000Z", "", "PASS", 0, "",
                      "", text))
    # a measurement row of the fleet report's query holding text where a number belongs
    conn.execute("INSERT INTO measurements VALUES ('bad-number', 'calibrate', 'accel.bias.x', 'lots', NULL, "
                 "'m/s^2', -0.5, 0.5, 'PASS')")
    conn.commit()
    conn.close()
    return db


def test_every_reader_refuses_a_hostile_row_in_one_line_and_reads_the_others(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = _hostile_db(tmp_path)
    code, out, err = _main(capsys, "records", "--db", str(db), "--json")
    assert code == ExitCode.OK and "Traceback" not in err
    assert sorted(r["serial"] for r in json.loads(out)) == ["A0", "A1", "A2"]
    refused = err.strip().splitlines()
    assert len(refused) == len(HOSTILE_ROWS), err
    for run_id in HOSTILE_ROWS:
        assert sum(run_id in line for line in refused) == 1, (run_id, refused)
    code, out, err = _main(capsys, "records", "--db", str(db), "--verify")
    assert code == ExitCode.OUT_OF_LIMITS and len(err.strip().splitlines()) == len(HOSTILE_ROWS), err
    code, out, err = _main(capsys, "records", "report", "--db", str(db), "--json")
    assert code == ExitCode.OK and "Traceback" not in err, err
    assert [line for line in err.strip().splitlines() if "bad-number" in line], err
    code, out, err = _main(capsys, "report", "--db", str(db), "--serial", "A1", "-o",
                           str(tmp_path / "c.html"))
    assert code == ExitCode.OK and "Traceback" not in err, err


# --- 5. attachments: inside the record's folder, regular files, bounded ---------------------------


def _with_attachments(tmp_path: Path) -> tuple[Path, RunRecord]:
    record = make_record("ATT", "2026-11-24T08:00:00.000000Z", tmp_path / "att")
    folder = tmp_path / "att"
    os.mkfifo(folder / "fifo.csv")
    (folder / "zero.csv").symlink_to("/dev/zero")
    (folder / "passwd.csv").symlink_to("/etc/passwd")
    extra = [Attachment("absolute", "/etc/passwd", "0" * 64, 10, "text/csv"),
             Attachment("dotdot", "../../../../etc/passwd", "0" * 64, 10, "text/csv"),
             Attachment("devzero", "/dev/zero", "0" * 64, 1 << 40, "text/csv"),
             Attachment("fifo", "fifo.csv", "0" * 64, 10, "text/csv"),
             Attachment("zero link", "zero.csv", "0" * 64, 1 << 40, "text/csv"),
             Attachment("passwd link", "passwd.csv", "0" * 64, 10, "text/csv")]
    record.phases[1].attachments += extra
    db = tmp_path / "r.sqlite"
    with RecordStore.open(db) as store:
        store.save(record)
    return db, record


def test_attachments_are_read_only_inside_the_folder_as_regular_files(tmp_path: Path) -> None:
    db, record = _with_attachments(tmp_path)
    problems = record.verify()
    assert len(problems) == 6, problems
    assert all("missing" in p for p in problems), problems
    # Each command in its own process, bounded: a FIFO or /dev/zero read would hang it.
    done = _cli("records", "--db", str(db), "--verify", cwd=tmp_path, timeout=60)
    assert done.returncode == ExitCode.OUT_OF_LIMITS and "Traceback" not in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 6 and "capture.csv" not in done.stderr
    done = _cli("report", "--db", str(db), "--serial", "ATT", "-o", str(tmp_path / "c.html"), cwd=tmp_path,
                timeout=60)
    assert done.returncode == ExitCode.OK and "Traceback" not in done.stderr, done.stderr
    assert "root:" not in (tmp_path / "c.html").read_text()


def test_an_attachment_the_size_of_the_record_is_read_no_further(tmp_path: Path) -> None:
    record = make_record("SZ", "2026-11-24T08:00:00.000000Z", tmp_path / "sz")
    capture = tmp_path / "sz" / "capture.csv"
    assert record.verify() == []
    capture.write_text(capture.read_text() + "1,2\n")
    assert "size does" in record.verify()[0]


# --- 2. data never reaches the terminal as markup -------------------------------------------------

HOSTILE_TEXT = {
    "station": "line-a[/]",
    "plan": "[link=file:///etc/passwd]plan[/link]",
    "reason": "[reverse]PASS[/]\x1b[2J\u202eevil",
    "serial": "SN[bold]1\x1b]0;t\x07",
}


def test_records_show_markup_and_control_characters_as_typed(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    db = tmp_path / "r.sqlite"
    record = RunRecord(serial=HOSTILE_TEXT["serial"], station=HOSTILE_TEXT["station"],
                       plan={"name": HOSTILE_TEXT["plan"], "sha256": ""}, start="2026-11-24T08:00:00.000000Z")
    record.finish("ABORTED", HOSTILE_TEXT["reason"])
    with RecordStore.open(db) as store:
        store.save(record)
    for args in (["records"], ["records", "--station", HOSTILE_TEXT["station"]]):
        code, out, err = _main(capsys, *args, "--db", str(db), "--export", str(tmp_path / "[b]x.json"))
        assert code == ExitCode.OK, err
        flat = "".join(out.split())
        for shown in ("line-a[/]", "[link=file:///etc/passwd]plan[/link]", "[reverse]PASS", "\\x1b",
                      "SN[bold]1", "[b]x.json"):
            assert shown in flat, (shown, out)
        assert "\x1b" not in out and "\u202e" not in out and "\x07" not in out


def test_run_many_table_shows_a_unit_label_and_reason_as_typed() -> None:
    from rich.console import Console

    unit = UnitProgress(UnitSpec("[red]u1[/]"), Path("x.log"), serial="[link=file:///etc/passwd]s",
                        reason="[/]\x1b[2J")
    unit.pending = "p.json"
    console = Console(width=200, record=True, file=open(os.devnull, "w"))  # noqa: SIM115
    console.print(summary_table([unit], "t"))
    text = console.export_text()
    assert "[red]u1[/]" in text and "[link=file:///etc/passwd]s" in text
    assert "\x1b" not in text and "\\x1b" in text
    assert "record pending" in text
