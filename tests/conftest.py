"""Shared fixtures: where the reference recordings are, and the optional real port."""

from __future__ import annotations

from pathlib import Path

import pytest

REFERENCE_DATA = Path(__file__).resolve().parent / "data"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--imu-port", default=None,
                     help="also run the device contract tests against this real serial port")
    parser.addoption("--chamber", default=None, metavar="URL",
                     help="also run the chamber contract tests against this real chamber "
                          "(votsch://HOST, espec:///dev/ttyUSB0, watlow-f4://PORT, binder://HOST)")
    parser.addoption("--supply", default=None, metavar="URL",
                     help="also run the supply contract test against this real bench supply (scpi://HOST, "
                          "korad:///dev/ttyUSB0); it sets at most 1 V and 50 mA and leaves the output off")
    parser.addoption("--table", default=None, metavar="URL",
                     help="also run the rate table contract test against this real table "
                          "(acutrol://HOST:PORT, aerosmith:///dev/ttyUSB0); it moves a few degrees")


@pytest.fixture(scope="session")
def reference_data() -> Path:
    """``tests/data``: real recordings made by others, with their licences (see its README.md)."""
    return REFERENCE_DATA
