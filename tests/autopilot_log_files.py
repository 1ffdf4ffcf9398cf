"""Small writers of PX4 ULog and ArduPilot DataFlash files for the autopilot-log tests and benchmark.

Both follow the formats' own documents, not any reader of them, so the readers are checked against
bytes written independently:

- ULog (PX4 ``docs/en/dev_log/ulog_file_format.md``): the 16-byte header (``ULog`` 0x01 0x12 0x35, version,
  uint64 start time), then messages of a 3-byte header (uint16 size without the header, uint8 type):
  ``B`` flag bits, ``I`` info, ``F`` formats, ``P`` parameters, then ``A`` subscriptions and ``D`` data
  (uint16 msg_id and the packed fields, trailing padding not written), with ``L`` logging and ``O``
  dropouts between them.
- DataFlash (ArduPilot ``libraries/AP_Logger/LogStructure.h``): every message starts 0xA3 0x95 and its
  type; type 0x80 ``FMT`` (Type, Length with the header, Name[4], Format[16], Columns[64]) defines the
  others; ``PARM`` (TimeUS, Name[16], Value) and ``IMU`` (TimeUS, I, GyrX..Z, AccX..Z, EG, EA, T, GH, AH,
  GHz, AHz) carry what the reader needs.

Messages are laid out with numpy (offsets computed, bytes scattered), so a 100 MB log takes seconds.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

ULOG_MAGIC = b"ULog\x01\x12\x35"

# PX4's own field lists (msg/SensorAccel.msg, msg/SensorGyro.msg as the logger writes them).
ACCEL_FORMAT = ("uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;"
                "float temperature;uint32_t error_count;uint8_t[3] clip_counter;uint8_t samples;"
                "uint8_t[4] _padding0;")
GYRO_FORMAT = ("uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;"
               "float temperature;uint32_t error_count;uint8_t samples;uint8_t[7] _padding0;")
ACCEL_DTYPE = np.dtype([("timestamp", "<u8"), ("timestamp_sample", "<u8"), ("device_id", "<u4"), ("x", "<f4"),
                        ("y", "<f4"), ("z", "<f4"), ("temperature", "<f4"), ("error_count", "<u4"),
                        ("clip_counter", "u1", 3), ("samples", "u1")])
MAG_FORMAT = ("uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;float z;"
              "float temperature;uint32_t error_count;bool is_external;uint8_t[7] _padding0;")
MAG_DTYPE = np.dtype([("timestamp", "<u8"), ("timestamp_sample", "<u8"), ("device_id", "<u4"), ("x", "<f4"),
                      ("y", "<f4"), ("z", "<f4"), ("temperature", "<f4"), ("error_count", "<u4"),
                      ("is_external", "?")])
GYRO_DTYPE = np.dtype([("timestamp", "<u8"), ("timestamp_sample", "<u8"), ("device_id", "<u4"), ("x", "<f4"),
                       ("y", "<f4"), ("z", "<f4"), ("temperature", "<f4"), ("error_count", "<u4"),
                       ("samples", "u1")])


def _message(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def imu_records(t_us: np.ndarray, acc: np.ndarray, gyro: np.ndarray, temp: np.ndarray, accel_id: int,
                gyro_id: int) -> tuple[np.ndarray, np.ndarray]:
    """sensor_accel and sensor_gyro records at the same timestamps (timestamp = timestamp_sample + 200 us)."""
    a = np.zeros(len(t_us), ACCEL_DTYPE)
    g = np.zeros(len(t_us), GYRO_DTYPE)
    for rec, values, dev in ((a, acc, accel_id), (g, gyro, gyro_id)):
        rec["timestamp_sample"] = t_us
        rec["timestamp"] = t_us + 200
        rec["device_id"] = dev
        rec["x"], rec["y"], rec["z"] = values[:, 0], values[:, 1], values[:, 2]
        rec["temperature"] = temp
        rec["samples"] = 1
    return a, g


def write_ulog(path: str | Path, topics: Mapping[tuple[str, int], np.ndarray], params: Mapping[str, float],
               formats: Mapping[str, str] | None = None, dropout_ms: int = 0) -> Path:
    """Write a ULog holding ``topics`` ((name, multi_id) -> structured records with a ``timestamp``).

    Data messages are interleaved in timestamp order; integer-valued parameters whose name ends in ``_ID``,
    ``_ENABLE``, ``_ROT`` or ``_EN`` are written as int32_t, the others as float. A dropout message of
    ``dropout_ms`` is put halfway through the data when it is non-zero.
    """
    formats = dict(formats or {"sensor_accel": ACCEL_FORMAT, "sensor_gyro": GYRO_FORMAT,
                               "sensor_mag": MAG_FORMAT})
    head = bytearray(ULOG_MAGIC + bytes([1]) + struct.pack("<Q", 0))
    head += _message(b"B", bytes(16) + bytes(24))
    for key, value in (("char[3] sys_name", b"PX4"), ("char[6] ver_hw", b"TESTHW")):
        head += _message(b"I", bytes([len(key)]) + key.encode() + value)
    for name, fields in formats.items():
        head += _message(b"F", f"{name}:{fields}".encode())
    for name, value in params.items():
        as_int = name.endswith(("_ID", "_ENABLE", "_ROT", "_EN")) or name == "SENS_BOARD_ROT"
        key = f"{'int32_t' if as_int else 'float'} {name}".encode()
        packed = struct.pack("<i", int(value)) if as_int else struct.pack("<f", value)
        head += _message(b"P", bytes([len(key)]) + key + packed)
    ids = {}
    for msg_id, (name, multi_id) in enumerate(topics):
        ids[name, multi_id] = msg_id
        head += _message(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode())
    head += _message(b"L", b"\x06" + struct.pack("<Q", 0) + b"logging started")
    # every data message: its time, its topic, its length; then the bytes scattered to their offsets
    keys = list(topics)
    if not keys:
        Path(path).write_bytes(bytes(head))
        return Path(path)
    times = np.concatenate([topics[k]["timestamp"] for k in keys])
    which = np.concatenate([np.full(len(topics[k]), i) for i, k in enumerate(keys)])
    order = np.argsort(times, kind="stable")
    sizes = np.array([5 + topics[k].dtype.itemsize for k in keys])[which[order]]
    extra = 5 if dropout_ms else 0
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    half = len(order) // 2
    starts[half:] += extra
    out = np.zeros(int(sizes.sum()) + extra, np.uint8)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    begin = 0
    for key in keys:
        recs = topics[key]
        n, size = len(recs), recs.dtype.itemsize
        at = starts[rank[begin:begin + n]]
        header = np.zeros(n, np.dtype([("size", "<u2"), ("type", "u1"), ("msg_id", "<u2")]))
        header["size"], header["type"], header["msg_id"] = size + 2, ord("D"), ids[key]
        block = np.concatenate([header.view(np.uint8).reshape(n, 5),
                                np.ascontiguousarray(recs).view(np.uint8).reshape(n, size)], axis=1)
        out[at[:, None] + np.arange(size + 5)] = block
        begin += n
    if dropout_ms:
        at = int(starts[half]) - extra
        out[at:at + extra] = np.frombuffer(_message(b"O", struct.pack("<H", dropout_ms)), np.uint8)
    path = Path(path)
    with open(path, "wb") as f:
        f.write(head)
        f.write(out.tobytes())
    return path


# --- DataFlash ------------------------------------------------------------------------------------------

HEAD = b"\xa3\x95"
FMT_TYPE = 0x80
IMU_COLUMNS = "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,EG,EA,T,GH,AH,GHz,AHz"
IMU_FORMAT = "QBffffffIIfBBHH"
IMU_DTYPE = np.dtype([("head", "u1", 2), ("type", "u1"), ("TimeUS", "<u8"), ("I", "u1"), ("GyrX", "<f4"),
                      ("GyrY", "<f4"), ("GyrZ", "<f4"), ("AccX", "<f4"), ("AccY", "<f4"), ("AccZ", "<f4"),
                      ("EG", "<u4"), ("EA", "<u4"), ("T", "<f4"), ("GH", "u1"), ("AH", "u1"), ("GHz", "<u2"),
                      ("AHz", "<u2")])


MAG_COLUMNS = "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S"
MAG_FORMAT_DF = "QBhhhhhhhhhBI"  # ArduPilot logs the field in whole milligauss
MAG_DF_DTYPE = np.dtype([("head", "u1", 2), ("type", "u1"), ("TimeUS", "<u8"), ("I", "u1"), ("MagX", "<i2"),
                         ("MagY", "<i2"), ("MagZ", "<i2"), ("OfsX", "<i2"), ("OfsY", "<i2"), ("OfsZ", "<i2"),
                         ("MOX", "<i2"), ("MOY", "<i2"), ("MOZ", "<i2"), ("Health", "u1"), ("S", "<u4")])


def mag_records(t_us: np.ndarray, field_gauss: np.ndarray, device_id: int) -> np.ndarray:
    """sensor_mag records (gauss) at ``t_us``."""
    rec = np.zeros(len(t_us), MAG_DTYPE)
    rec["timestamp_sample"] = t_us
    rec["timestamp"] = t_us + 300
    rec["device_id"] = device_id
    rec["x"], rec["y"], rec["z"] = field_gauss[:, 0], field_gauss[:, 1], field_gauss[:, 2]
    return rec


def mag_messages(t_us: np.ndarray, instance: int, field_mgauss: np.ndarray,
                 motor_mgauss: np.ndarray | None = None, mag_type: int = 131) -> np.ndarray:
    """MAG messages of one compass (header included), field rounded to whole milligauss as logged."""
    rec = np.zeros(len(t_us), MAG_DF_DTYPE)
    rec["head"] = (0xA3, 0x95)
    rec["type"] = mag_type
    rec["TimeUS"] = t_us
    rec["I"] = instance
    for j, axis in enumerate("XYZ"):
        rec[f"Mag{axis}"] = np.rint(field_mgauss[:, j])
        if motor_mgauss is not None:
            rec[f"MO{axis}"] = np.rint(motor_mgauss[:, j])
    rec["Health"] = 1
    return rec


def _fmt(msg_type: int, length: int, name: str, fmt: str, columns: str) -> bytes:
    return HEAD + struct.pack("<BBB4s16s64s", FMT_TYPE, msg_type, length, name.encode(), fmt.encode(),
                              columns.encode())


def imu_messages(t_us: np.ndarray, instance: int, acc: np.ndarray, gyro: np.ndarray,
                 temp: np.ndarray, imu_type: int = 130) -> np.ndarray:
    """IMU messages of one instance as records of :data:`IMU_DTYPE` (header included)."""
    rec = np.zeros(len(t_us), IMU_DTYPE)
    rec["head"] = (0xA3, 0x95)
    rec["type"] = imu_type
    rec["TimeUS"] = t_us
    rec["I"] = instance
    for j, axis in enumerate("XYZ"):
        rec[f"Gyr{axis}"] = gyro[:, j]
        rec[f"Acc{axis}"] = acc[:, j]
    rec["T"] = temp
    rec["GH"] = rec["AH"] = 1
    rec["GHz"] = rec["AHz"] = 400
    return rec


def write_dataflash(path: str | Path, imu: list[np.ndarray], params: Mapping[str, float],
                    mag: list[np.ndarray] = ()) -> Path:
    """Write a DataFlash log: FMT of FMT, PARM, IMU and MAG, the parameters, then the IMU messages of every
    instance in ``imu`` interleaved by TimeUS, then the MAG messages of ``mag``."""
    parm_type, imu_type, mag_type = 129, 130, 131
    out = bytearray(_fmt(FMT_TYPE, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns"))
    out += _fmt(parm_type, 31, "PARM", "QNf", "TimeUS,Name,Value")
    out += _fmt(imu_type, IMU_DTYPE.itemsize, "IMU", IMU_FORMAT, IMU_COLUMNS)
    out += _fmt(mag_type, MAG_DF_DTYPE.itemsize, "MAG", MAG_FORMAT_DF, MAG_COLUMNS)
    for name, value in params.items():
        out += HEAD + struct.pack("<BQ16sf", parm_type, 0, name.encode(), value)
    records = np.concatenate(imu) if imu else np.zeros(0, IMU_DTYPE)
    records = records[np.argsort(records["TimeUS"], kind="stable")]
    out += records.tobytes()
    for rec in mag:
        out += rec.tobytes()
    path = Path(path)
    path.write_bytes(bytes(out))
    return path


# --- from simulated captures ----------------------------------------------------------------------------

ACCEL_IDS = (1310988, 1310996, 1311004)  # PX4 SITL's three simulated IMUs
GYRO_IDS = (2359308, 2359316, 2359324)


def ulog_from_captures(path: str | Path, captures: Mapping[int, Any],
                       params: Mapping[str, float] | None = None, dropout_ms: int = 0) -> Path:
    """A ULog whose sensor_accel/sensor_gyro multi_id i hold capture i (float32 on disk)."""
    topics = {}
    for i, cap in captures.items():
        t_us = np.rint(np.asarray(cap.t) * 1e6).astype(np.uint64)
        temp = cap.temp if cap.temp is not None else np.zeros(len(t_us))
        a, g = imu_records(t_us, np.asarray(cap.acc), np.asarray(cap.gyro), temp, ACCEL_IDS[i], GYRO_IDS[i])
        topics["sensor_accel", i], topics["sensor_gyro", i] = a, g
        if cap.mag is not None:  # microtesla to PX4's gauss, at the IMU's times
            topics["sensor_mag", i] = mag_records(t_us, np.asarray(cap.mag) / 100.0, 396825 + 8 * i)
    return write_ulog(path, topics, dict(params or {}), dropout_ms=dropout_ms)


def dataflash_from_captures(path: str | Path, captures: Mapping[int, Any],
                            params: Mapping[str, float] | None = None) -> Path:
    """A DataFlash log whose IMU instance i holds capture i as logged (no correction applied to it)."""
    imu = []
    for i, cap in captures.items():
        t_us = np.rint(np.asarray(cap.t) * 1e6).astype(np.uint64)
        temp = cap.temp if cap.temp is not None else np.zeros(len(t_us))
        imu.append(imu_messages(t_us, i, np.asarray(cap.acc), np.asarray(cap.gyro), temp))
    return write_dataflash(path, imu, dict(params or {}))
