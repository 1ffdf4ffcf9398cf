"""The metadata lines of a capture CSV (``shared/specs/capture-csv.md``): ``# key: value`` before the header.

The station writes the unit's ``serial``, ``model``, ``firmware``, ``protocol`` and ``rate_hz`` and the
file's ``created`` (ISO 8601, UTC), so that a capture names the unit it came from as the HDF5 capture
file does; a key whose value is unknown is written empty. Readers keep every key (unknown ones too) and
take an empty value for an unknown one.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Mapping
from typing import Any

from station.common.text import printable

WRITTEN_KEYS = ("serial", "model", "firmware", "protocol", "rate_hz", "created")
"""The keys the station writes, in this order (``instances`` follows when a file holds several IMUs, and
``instance`` when it holds one IMU instance of a board of several)."""
MAX_VALUE_CHARS = 1000
"""A value longer than this is cut: a metadata line stays a short line whatever a unit reports."""
MAX_LINES = 256
"""The most metadata lines a reader takes before the header: a file of endless ``#`` lines is refused."""


def csv_metadata(device: Mapping[str, Any] | None, protocol: str = "") -> dict[str, str]:
    """The metadata of a capture CSV written from the unit ``device`` describes.

    Parameters
    ----------
    device : mapping or None
        What the unit reported (its DEVICE_INFO: serial, model, firmware, rate_hz), or what a
        capture read from a file holds.
    protocol : str
        The wire protocol the samples came in (``native``, ``frame:board.yaml``); empty: the one
        ``device`` names, if any.

    Returns
    -------
    dict
        Key to value, every key of ``WRITTEN_KEYS`` (empty where unknown), then ``instances`` and
        ``instance`` if known.
    """
    device = device or {}
    values: dict[str, Any] = {key: device.get(key) for key in ("serial", "model", "firmware")}
    values["protocol"] = protocol or device.get("protocol")
    values["rate_hz"] = device.get("rate_hz")
    values["created"] = dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    if device.get("instances") is not None:
        values["instances"] = device["instances"]
    # one file per IMU instance of a board (station.acquisition.instance_capture): which one this is
    if device.get("instance") is not None:
        values["instance"] = device["instance"]
    return {key: _one_line(value) for key, value in values.items()}


def _one_line(value: Any) -> str:
    # a value from a unit may hold a line break or an escape sequence: it must not end the line or
    # start a row, so such characters are written as escapes (backslashes are kept as sent)
    return "" if value is None else printable(value, MAX_VALUE_CHARS, escape_backslash=False)


def metadata_text(metadata: Mapping[str, str]) -> str:
    """The ``# key: value`` lines of ``metadata``, each ended by a newline."""
    return "".join(f"# {key}: {value}\n" for key, value in metadata.items())


def parse_line(line: str) -> tuple[str, str] | None:
    """The key and value of one ``# key: value`` line, or None for a comment of another form."""
    body = line.rstrip("\r\n")[1:]
    key, sep, value = body.partition(":")
    key = key.strip()
    if not sep or not key or " " in key:
        return None
    return key, value.strip()


def device_of(metadata: Mapping[str, str]) -> dict[str, Any]:
    """The capture's device info from its metadata: every key with a value, ``rate_hz`` as a number."""
    device: dict[str, Any] = {key: value for key, value in metadata.items() if value != ""}
    if "rate_hz" in device:
        try:
            rate = float(device["rate_hz"])
        except ValueError:
            pass  # kept as written: a reader ignores what it does not understand
        else:
            device["rate_hz"] = int(rate) if rate.is_integer() else rate
    return device
