"""IMU samples from ROS 1 bags and ROS 2 bags (sqlite3 or mcap), ``sensor_msgs/Imu``, through ``rosbags``.

Samples are timed by their header stamps (the sensor's clock), not by the bag's receive times, and come
in the bag's order: checking that the stamps increase is the caller's job (see ``allan_source``).
``rosbags`` is the optional extra ``ros``: ``pip install 'imu-station[ros]'``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from station.errors import InputFileError

IMU_TYPES = ("sensor_msgs/msg/Imu", "sensor_msgs/Imu")
CHUNK_ROWS = 100_000


def is_rosbag(path: str | Path) -> bool:
    """A ROS 1 ``.bag`` file, a ROS 2 bag folder (metadata.yaml) or one of its ``.db3``/``.mcap`` files.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
    """
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").exists()
    return path.suffix in (".bag", ".db3", ".mcap")


def _bag_paths(path: Path) -> list[Path]:
    if path.suffix in (".db3", ".mcap") and (path.parent / "metadata.yaml").exists():
        return [path.parent]
    return [path]


def _open(path: Path):
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise InputFileError(path, "is a ROS bag, and reading bags needs the optional extra 'ros': "
                             "pip install 'imu-station[ros]'") from None
    if not path.exists():
        raise InputFileError(path, "does not exist; give a ROS 1 .bag file or a ROS 2 bag directory")
    # Older ROS 2 bags carry no message definitions: fall back to the standard ones.
    return AnyReader(_bag_paths(path), default_typestore=get_typestore(Stores.ROS2_HUMBLE))


def imu_topics(path: str | Path) -> dict[str, int]:
    """The ``sensor_msgs/Imu`` topics of a bag and their message counts.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict of str to int

    Raises
    ------
    InputFileError
        No ``rosbags`` installed, or a bag that cannot be read.
    """
    path = Path(path)
    reader = _open(path)
    try:
        with reader:
            return {c.topic: c.msgcount for c in reader.connections if c.msgtype in IMU_TYPES}
    except Exception as exc:  # rosbags raises many kinds on a damaged bag
        if isinstance(exc, InputFileError):
            raise
        raise InputFileError(path, f"cannot be read as a ROS bag: {exc}") from None


def _choose_topic(path: Path, topics: dict[str, int], topic: str | None) -> str:
    if not topics:
        raise InputFileError(path, "has no sensor_msgs/Imu topic; record the IMU topic of the unit")
    if topic is None:
        if len(topics) > 1:
            raise InputFileError(path, f"has several IMU topics {sorted(topics)}; choose one with --topic")
        return next(iter(topics))
    if topic not in topics:
        raise InputFileError(path, f"has no IMU topic {topic!r}; its IMU topics are {sorted(topics)}")
    return topic


def iter_imu_chunks(path: str | Path, topic: str | None = None, chunk_rows: int = CHUNK_ROWS
                    ) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Yield (t, acc, gyro) batches of at most ``chunk_rows`` samples in bag order.

    ``t`` is the header stamp in seconds from the first message's stamp (float64: absolute epoch seconds
    would keep only 0.2 us), ``acc`` the linear acceleration (m/s^2) and ``gyro`` the angular velocity
    (rad/s), shape (n, 3) each. With ``topic`` None the bag must hold exactly one
    IMU topic.

    Parameters
    ----------
    path : str or Path
    topic : str, optional
    chunk_rows : int

    Yields
    ------
    tuple of ndarray
        (t, acc, gyro).

    Raises
    ------
    InputFileError
        No IMU topic, several without ``topic``, or no such topic.
    """
    path = Path(path)
    chosen = _choose_topic(path, imu_topics(path), topic)
    reader = _open(path)
    with reader:
        conns = [c for c in reader.connections if c.topic == chosen and c.msgtype in IMU_TYPES]
        stamp = np.empty(chunk_rows, dtype=np.int64)
        origin = None
        values = np.empty((chunk_rows, 6), dtype=np.float64)
        n = 0
        for conn, _, raw in reader.messages(connections=conns):
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:  # a truncated or foreign message
                raise InputFileError(path, f"message {n} on {chosen} cannot be decoded: {exc}") from None
            ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
            if origin is None:
                origin = ns
            stamp[n] = ns - origin
            a, w = msg.linear_acceleration, msg.angular_velocity
            values[n] = (a.x, a.y, a.z, w.x, w.y, w.z)
            n += 1
            if n == chunk_rows:
                yield _batch(stamp, values, n)
                n = 0
        if n:
            yield _batch(stamp, values, n)


def _batch(stamp_ns: np.ndarray, values: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return stamp_ns[:n] * 1e-9, values[:n, :3].copy(), values[:n, 3:].copy()
