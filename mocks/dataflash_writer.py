"""A writer of ArduPilot DataFlash (``.bin``) logs, for simulated flight-controller logs.

The layout is ArduPilot's (``libraries/AP_Logger/LogStructure.h``): every message is the two bytes
``0xA3 0x95``, a uint8 message type, then its fields packed little endian as its format string
says. Type 0x80, ``FMT``, describes the others and is itself fixed::

    FMT  "BBnNZ"  Type, Length (whole message, header included), Name (char[4]), Format (char[16]),
                  Columns (char[64])

Format characters (the same header): ``b``/``B`` int8/uint8, ``h``/``H`` int16/uint16, ``i``/``I``
int32/uint32, ``q``/``Q`` int64/uint64, ``f`` float, ``d`` double, ``n`` char[4], ``N`` char[16],
``Z`` char[64], ``c``/``C`` int16/uint16 * 100, ``e``/``E`` int32/uint32 * 100, ``L`` int32
latitude/longitude, ``M`` uint8 flight mode.

The messages written are ArduPilot's own:

- ``PARM`` ``"QNff"`` TimeUS, Name, Value, Default (``LOG_PARAMETER_MSG``);
- ``IMU`` ``"QBffffffIIfBBHH"`` TimeUS, I, GyrX, GyrY, GyrZ, AccX, AccY, AccZ, EG, EA, T, GH, AH, GHz,
  AHz (``AP_InertialSensor/LogStructure.h``): rad/s, m/s^2 in the body frame, degC, instance ``I``.

IMU messages of all instances are interleaved by TimeUS and laid out as one numpy record array.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

HEAD = b"\xa3\x95"
FMT_TYPE = 0x80
FMT_FORMAT, FMT_COLUMNS = "BBnNZ", "Type,Length,Name,Format,Columns"
PARM_TYPE, PARM_FORMAT, PARM_COLUMNS = 0x40, "QNff", "TimeUS,Name,Value,Default"
IMU_TYPE = 0x41
IMU_FORMAT = "QBffffffIIfBBHH"
IMU_COLUMNS = "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"

# LogStructure.h's format characters as numpy types (only those this writer needs)
FORMAT_TYPES: dict[str, str] = {
    "b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8", "Q": "<u8",
    "f": "<f4", "d": "<f8", "n": "S4", "N": "S16", "Z": "S64",
}


def message_dtype(fmt: str, columns: str) -> np.dtype:
    """One whole message (header bytes, type, then the columns) as a packed numpy record type."""
    names = columns.split(",")
    if len(names) != len(fmt):
        raise ValueError(f"format {fmt!r} has {len(fmt)} fields but {len(names)} columns")
    return np.dtype([("head", "u1", (2,)), ("type", "u1")]
                    + [(name, FORMAT_TYPES[c]) for name, c in zip(names, fmt, strict=True)])


IMU_DTYPE = message_dtype(IMU_FORMAT, IMU_COLUMNS)
PARM_DTYPE = message_dtype(PARM_FORMAT, PARM_COLUMNS)


FMT_LENGTH = 89  # 3 header bytes + B, B, char[4], char[16], char[64]


def _fmt(msg_type: int, length: int, name: str, fmt: str, columns: str) -> bytes:
    return HEAD + struct.pack("<BBB4s16s64s", FMT_TYPE, msg_type, length, name.encode("ascii"),
                              fmt.encode("ascii"), columns.encode("ascii"))


def imu_messages(time_us: np.ndarray, instance: int, acc: np.ndarray, gyro: np.ndarray, temp: np.ndarray,
                 rate_hz: float) -> np.ndarray:
    """The ``IMU`` messages of one instance (records of :data:`IMU_DTYPE`, header included).

    Parameters
    ----------
    time_us : ndarray, (N,)
        TimeUS, microseconds since boot.
    instance : int
        ``I``, 0-based.
    acc, gyro : ndarray, (N, 3)
        m/s^2 and rad/s.
    temp : ndarray, (N,)
        degC.
    rate_hz : float
        GHz and AHz, the sensors' rates; GH and AH (health) are 1.

    Returns
    -------
    ndarray
    """
    rec = np.zeros(len(time_us), IMU_DTYPE)
    rec["head"] = np.frombuffer(HEAD, np.uint8)
    rec["type"] = IMU_TYPE
    rec["TimeUS"] = time_us
    rec["I"] = instance
    for j, axis in enumerate("XYZ"):
        rec[f"Gyr{axis}"] = gyro[:, j]
        rec[f"Acc{axis}"] = acc[:, j]
    rec["T"] = temp
    rec["GH"] = rec["AH"] = 1
    rec["GHz"] = rec["AHz"] = int(round(rate_hz))
    return rec


def parm_messages(params: Mapping[str, float], time_us: int = 0) -> np.ndarray:
    """``PARM`` messages (records of :data:`PARM_DTYPE`), the default equal to the value.

    Raises
    ------
    ValueError
        A name longer than ArduPilot's 16 characters.
    """
    rec = np.zeros(len(params), PARM_DTYPE)
    rec["head"] = np.frombuffer(HEAD, np.uint8)
    rec["type"] = PARM_TYPE
    rec["TimeUS"] = time_us
    for k, (name, value) in enumerate(params.items()):
        if len(name) > 16:
            raise ValueError(f"parameter name {name!r} is longer than DataFlash's 16 characters")
        rec["Name"][k] = name.encode("ascii")
        rec["Value"][k] = rec["Default"][k] = value
    return rec


def write_dataflash(path: str | Path, imu: Sequence[np.ndarray], params: Mapping[str, float] | None = None,
                    params_time_us: int = 0) -> Path:
    """Write a DataFlash log: the FMT messages (FMT, PARM, IMU), the parameters, then every IMU
    message of ``imu`` (one array of :func:`imu_messages` per instance) in TimeUS order.

    Parameters
    ----------
    path : str or Path
    imu : sequence of ndarray
    params : mapping, optional
    params_time_us : int
        TimeUS of the PARM messages.

    Returns
    -------
    Path
    """
    out = bytearray(_fmt(FMT_TYPE, FMT_LENGTH, "FMT", FMT_FORMAT, FMT_COLUMNS))
    out += _fmt(PARM_TYPE, PARM_DTYPE.itemsize, "PARM", PARM_FORMAT, PARM_COLUMNS)
    out += _fmt(IMU_TYPE, IMU_DTYPE.itemsize, "IMU", IMU_FORMAT, IMU_COLUMNS)
    out += parm_messages(params or {}, params_time_us).tobytes()
    records = np.concatenate(list(imu)) if len(imu) else np.zeros(0, IMU_DTYPE)
    records = records[np.argsort(records["TimeUS"], kind="stable")]
    path = Path(path)
    with open(path, "wb") as f:
        f.write(bytes(out))
        f.write(records.tobytes())
    return path
