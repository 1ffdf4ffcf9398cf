"""ArduPilot DataFlash logs (``.bin``): parameters and IMU messages, through pymavlink's DFReader.

The format (ArduPilot ``libraries/AP_Logger/LogStructure.h``): every message is 0xA3 0x95, a type byte
and a payload whose layout the type's ``FMT`` message (type 0x80: Type, Length, Name[4], Format[16],
Columns[64]) gives, one character per column (``B`` uint8, ``f`` float, ``Q`` uint64, ``c`` int16 x 0.01,
...: ``pymavlink.DFReader.FORMAT_TO_STRUCT``). pymavlink's ``DFReader_binary`` finds every message's
offset (its compiled indexer) and the formats; the IMU payloads are then copied into one array and
viewed with the numpy dtype of their format, multipliers applied as DFReader applies them, so the values
are DFReader's own without one Python object per message.

An ``IMU`` message (``TimeUS, I, GyrX..Z, AccX..Z, EG, EA, T, ...``) names its instance in ``I``; logs
of firmware before 4.1 write ``IMU``, ``IMU2``, ``IMU3`` without it. pymavlink is the optional extra
``logs`` (``pip install 'imu-station[logs]'``).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from station.errors import InputFileError

HEAD = b"\xa3\x95\x80"
IMU_NAMES = ("IMU", "IMU2", "IMU3")
MAG_NAMES = ("MAG", "MAG2", "MAG3")


@dataclass
class DataflashData:
    """What :func:`read_dataflash` found: IMU and MAG records (float64 columns by name) per instance."""

    path: Path
    imus: dict[int, dict[str, np.ndarray]]
    params: dict[str, float]
    messages: dict[str, int]  # message counts by name
    mags: dict[int, dict[str, np.ndarray]] = field(default_factory=dict)


def is_dataflash(path: str | Path) -> bool:
    """Whether the file starts with a DataFlash FMT message (0xA3 0x95 0x80).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
    """
    try:
        with open(path, "rb") as f:
            return f.read(3) == HEAD
    except OSError:
        return False


def _dtype(fmt) -> tuple[np.dtype, dict[str, float]]:
    """The numpy dtype of a format's payload (after the 3-byte header) and its columns' multipliers."""
    from pymavlink.DFReader import FORMAT_TO_STRUCT

    names, kinds, mults = [], [], {}
    for column, char in zip(fmt.columns, fmt.msg_fmts, strict=False):
        code, mult, _ = FORMAT_TO_STRUCT[char]
        kind = f"S{code[:-1]}" if code.endswith("s") else ("<f2" if code == "e" else f"<{code}")
        names.append(column)
        kinds.append(kind)
        if mult is not None:
            mults[column] = mult
    return np.dtype({"names": names, "formats": kinds}), mults


def board_rotation(orientation: int) -> np.ndarray:
    """ArduPilot's board rotation R (body = R board) of ``AHRS_ORIENTATION``, from pymavlink's table.

    Parameters
    ----------
    orientation : int
        ``AHRS_ORIENTATION`` (ArduPilot's ``enum Rotation``).

    Returns
    -------
    ndarray, (3, 3)

    Raises
    ------
    ValueError
        A value the table does not hold (a custom rotation, 100 and up).
    """
    from pymavlink.rotmat import rotations

    if not 0 <= orientation < len(rotations):
        raise ValueError(f"rotation {orientation} is not one of ArduPilot's 0..{len(rotations) - 1}")
    r = rotations[orientation].r
    return np.array([[r.a.x, r.a.y, r.a.z], [r.b.x, r.b.y, r.b.z], [r.c.x, r.c.y, r.c.z]])


def read_dataflash(path: str | Path) -> DataflashData:
    """Read a DataFlash log's parameters (``PARM``, the first value of each) and IMU messages.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    DataflashData

    Raises
    ------
    InputFileError
        No pymavlink, not a DataFlash log, or a log pymavlink cannot index.
    """
    path = Path(path)
    try:
        from pymavlink.DFReader import DFReader_binary
    except ImportError:
        raise InputFileError(path, "is an ArduPilot DataFlash log, and reading it needs pymavlink: "
                             "pip install 'imu-station[logs]'") from None
    if not is_dataflash(path):
        raise InputFileError(path, "is not an ArduPilot DataFlash log (it does not start with an FMT "
                             "message, 0xA3 0x95 0x80); give the .bin the autopilot wrote")
    try:
        reader = DFReader_binary(str(path))
    except Exception as exc:  # pymavlink raises many kinds on a damaged log
        raise InputFileError(path, f"cannot be indexed as a DataFlash log: {exc}") from None
    try:
        return _read(reader, path)
    except (struct.error, KeyError, ValueError, TypeError) as exc:
        raise InputFileError(path, f"cannot be read as a DataFlash log: {exc}") from None
    finally:
        reader.close()  # every array into its map is gone with _read's frame: the map can close


def _read(reader, path: Path) -> DataflashData:
    """The parameters and IMU columns, copied out of the map DFReader indexed."""
    from station.acquisition.ulog_reader import gather_rows

    buf = np.frombuffer(reader.data_map, dtype=np.uint8)
    by_name = {f.name: t for t, f in reader.formats.items()}
    counts = {f.name: len(reader.offsets[t]) for t, f in reader.formats.items() if reader.offsets[t]}

    def records(name: str) -> tuple[np.ndarray, dict[str, float]]:
        fmt = reader.formats[by_name[name]]
        dtype, mults = _dtype(fmt)
        starts = np.asarray(reader.offsets[by_name[name]], dtype=np.int64)
        # a last message cut by the end of the file is left out, as DFReader leaves it
        starts = starts[starts + 3 + dtype.itemsize <= len(buf)] + 3
        return gather_rows(buf, starts, dtype.itemsize).reshape(-1).view(dtype), mults

    params: dict[str, float] = {}
    if "PARM" in by_name:
        parm, _ = records("PARM")
        for name, value in zip(parm["Name"], parm["Value"], strict=True):
            params.setdefault(name.rstrip(b"\x00").decode("ascii", "replace"), float(value))
    def by_instance(names: tuple[str, ...]) -> dict[int, dict[str, np.ndarray]]:
        # one message with an instance field I, or (firmware before 4.1) one message name per instance
        out: dict[int, dict[str, np.ndarray]] = {}
        for number, name in enumerate(names):
            if name not in by_name or not reader.offsets[by_name[name]]:
                continue
            rec, mults = records(name)
            columns = {c: rec[c] if rec.dtype[c].kind == "S"
                       else rec[c].astype(np.float64) * mults.get(c, 1.0) for c in rec.dtype.names or ()}
            if "I" in columns and number == 0:
                instance = rec["I"]
                for i in np.unique(instance):
                    keep = instance == i
                    out[int(i)] = {c: v[keep] for c, v in columns.items()}
            else:
                out[number] = columns
        return out

    return DataflashData(path, by_instance(IMU_NAMES), params, counts, by_instance(MAG_NAMES))
