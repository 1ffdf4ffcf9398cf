"""The station's HDF5 capture file: samples as recorded, with the unit's info and the link statistics.

Layout (schema ``imu-station/capture/1``)::

    /                attrs: schema, schema_version, created_utc, station_version, port, protocol,
                            device (JSON of DEVICE_INFO), link (JSON of the link statistics),
                            step_labels (JSON list; index 0 is "")
    /seq             (N,)   uint32   sample counter as sent by the unit
    /t_us            (N,)   uint64   device clock, microseconds
    /acc             (N, 3) float32  m/s^2, raw specific force
    /gyro            (N, 3) float32  rad/s, raw
    /temp            (N,)   float32  degC
    /step            (N,)   uint16   index into step_labels (only when the capture has labels)
    /mag             (N, 3) float32  uT, raw magnetic field; NaN rows carry none (only for a unit
                                     with a magnetometer)

Datasets are chunked and resizable; the writer appends batches and flushes at least once a
second (the recorder calls :meth:`H5CaptureWriter.flush`), so a capture cut short is readable.
Readers refuse any other schema.
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from protocols.base import MAG_SAMPLE_DTYPE, SAMPLE_DTYPE, has_mag
from station import __version__
from station.acquisition.capture_data import Capture
from station.errors import InputFileError, OutputFileError

SCHEMA = "imu-station/capture/1"
SCHEMA_VERSION = 1
CHUNK_ROWS = 4096
_COLUMNS = {  # dataset -> (dtype, row shape, unit)
    "seq": ("<u4", (), ""),
    "t_us": ("<u8", (), "us"),
    "acc": ("<f4", (3,), "m/s^2"),
    "gyro": ("<f4", (3,), "rad/s"),
    "temp": ("<f4", (), "degC"),
}
_MAG_COLUMN = ("<f4", (3,), "uT")


class H5CaptureWriter:
    """Appends sample batches to a new station capture file at ``path``."""

    def __init__(self, path: str | Path, device: dict[str, Any] | None = None, with_step: bool = False,
                 port: str = "", protocol: str = ""):
        self.path = Path(path)
        self.rows = 0
        self.field_dropped = 0  # never: a field that comes late gets its dataset then
        self._broken = False
        self._labels: list[str] = [""]
        self._label_index = {"": 0}
        try:
            self._file = h5py.File(self.path, "w")
        except OSError as exc:
            raise OutputFileError(self.path, f"cannot be created ({exc}); choose another path") from None
        f = self._file
        f.attrs["schema"] = SCHEMA
        f.attrs["schema_version"] = SCHEMA_VERSION
        f.attrs["created_utc"] = dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
        f.attrs["station_version"] = __version__
        f.attrs["port"] = port
        f.attrs["protocol"] = protocol
        f.attrs["device"] = json.dumps(device or {})
        f.attrs["link"] = json.dumps({})
        columns = dict(_COLUMNS)
        if with_step:
            columns["step"] = ("<u2", (), "")
            f.attrs["step_labels"] = json.dumps(self._labels)
        for name, (dtype, shape, unit) in columns.items():
            self._create(name, dtype, shape, unit)
        self._datasets = {name: f[name] for name in columns}
        self._with_step = with_step

    def _create(self, name: str, dtype: str, shape: tuple[int, ...], unit: str) -> h5py.Dataset:
        ds = self._file.create_dataset(name, shape=(self.rows, *shape), maxshape=(None, *shape),
                                       dtype=dtype, chunks=(CHUNK_ROWS, *shape),
                                       fillvalue=np.nan if name == "mag" else None)
        if unit:
            ds.attrs["unit"] = unit
        return ds

    def write(self, samples: np.ndarray, step: np.ndarray | list[str] | None = None) -> None:
        """Append a batch of samples (and their step labels) to the capture's datasets."""
        n = len(samples)
        if n == 0:
            return
        columns = {name: samples[name] for name in _COLUMNS}
        if has_mag(samples) and "mag" not in self._datasets:
            # The first field of the stream: rows written before it had none (NaN, the fill value).
            self._datasets["mag"] = self._create("mag", *_MAG_COLUMN)
        if "mag" in self._datasets:
            columns["mag"] = samples["mag"] if has_mag(samples) else np.full((n, 3), np.nan, np.float32)
        if self._with_step:
            labels = [""] * n if step is None else step
            columns["step"] = np.array([self._code(str(lab)) for lab in labels], dtype=np.uint16)
        try:
            # Grow every dataset first, then fill: a reader never sees one column longer than another
            # for longer than this call.
            end = self.rows + n
            for name, values in columns.items():
                ds = self._datasets[name]
                ds.resize(end, axis=0)
                ds[self.rows:end] = values
        except (OSError, RuntimeError) as exc:
            self._abandon()
            raise OutputFileError(self.path, f"writing failed ({exc}); the file may be incomplete or damaged "
                                  f"after {self.rows} samples; free space and capture again") from None
        self.rows = end

    def _code(self, label: str) -> int:
        code = self._label_index.get(label)
        if code is None:
            code = self._label_index[label] = len(self._labels)
            self._labels.append(label)
        return code

    def flush(self, link: dict[str, Any] | None = None) -> None:
        """Write the metadata so far and flush everything to the file."""
        try:
            if link is not None:
                self._file.attrs["link"] = json.dumps(link)
            if self._with_step:
                self._file.attrs["step_labels"] = json.dumps(self._labels)
            self._file.flush()
        except (OSError, RuntimeError) as exc:
            self._abandon()
            raise OutputFileError(self.path, f"flushing failed ({exc}); the file may be incomplete or "
                                  f"damaged; free space and capture again") from None

    def set_device(self, device: dict[str, Any]) -> None:
        """Store the device description (JSON) in the file's ``device`` attribute."""
        self._file.attrs["device"] = json.dumps(device)

    def close(self, link: dict[str, Any] | None = None) -> None:
        """Flush with the final link statistics ``link`` and close the file."""
        if self._broken or not self._file:
            return
        self.flush(link)
        self._file.close()

    def _abandon(self) -> None:
        self._broken = True
        try:
            self._file.close()
        except (OSError, RuntimeError):
            pass


def _open_checked(path: Path) -> h5py.File:
    """Open a capture file for reading after checking its schema and the shape of its datasets."""
    if not path.exists():
        raise InputFileError(path, "does not exist; give a capture file (.h5) or capture CSV")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputFileError(path, f"is not a readable HDF5 file ({exc})") from None
    try:
        schema = f.attrs.get("schema")
        if isinstance(schema, bytes):
            schema = schema.decode("utf-8", "replace")
        if schema != SCHEMA:
            raise InputFileError(path, f"has schema {schema!r}; this station reads {SCHEMA!r} (a newer "
                                 f"imu-station may read it)", column="schema")
        for name in _COLUMNS:
            if name not in f:
                raise InputFileError(path, "lacks a required dataset", column=name)
        n = len(f["t_us"])
        for name in (*_COLUMNS, "step", "mag"):
            if name in f and len(f[name]) != n:
                raise InputFileError(path, f"dataset has {len(f[name])} rows, t_us has {n}", column=name)
    except BaseException:
        f.close()
        raise
    return f


def read_h5(path: str | Path) -> Capture:
    """Read a station capture file into a :class:`Capture`; refuses other schemas and bad files."""
    path = Path(path)
    with _open_checked(path) as f:
        t_us = f["t_us"][:]
        bad = np.flatnonzero(np.diff(t_us.astype(np.int64)) <= 0)
        if len(bad):
            raise InputFileError(path, f"t_us does not increase at row {int(bad[0]) + 1}; rows must be in "
                                 f"time order", column="t_us")
        step = None
        if "step" in f:
            labels = np.array(json.loads(f.attrs.get("step_labels", '[""]')), dtype=object)
            codes = f["step"][:]
            if len(codes) and codes.max() >= len(labels):
                raise InputFileError(path, "step codes do not match step_labels", column="step")
            step = labels[codes]
        return Capture(
            t=t_us * 1e-6,
            acc=f["acc"][:].astype(np.float64),
            gyro=f["gyro"][:].astype(np.float64),
            temp=f["temp"][:].astype(np.float64),
            step=step,
            device=json.loads(f.attrs.get("device", "{}")),
            link=json.loads(f.attrs.get("link", "{}")),
            source=str(path),
            mag=f["mag"][:].astype(np.float64) if "mag" in f else None,
        )


def read_samples(path: str | Path) -> np.ndarray:
    """The records of a capture file as ``protocols.base.SAMPLE_DTYPE`` (``MAG_SAMPLE_DTYPE`` when it
    has a ``mag`` dataset), bit-exact as received."""
    with _open_checked(Path(path)) as f:
        names = (*_COLUMNS, "mag") if "mag" in f else tuple(_COLUMNS)
        out = np.zeros(len(f["t_us"]), dtype=MAG_SAMPLE_DTYPE if "mag" in f else SAMPLE_DTYPE)
        for name in names:
            out[name] = f[name][:]
    return out
