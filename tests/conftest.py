"""Shared fixtures: where the reference recordings are, and the optional real port."""

from __future__ import annotations

from pathlib import Path

import pytest

REFERENCE_DATA = Path(__file__).resolve().parent / "data"
# Modules whose tests pace a simulated unit, an instrument or a factory run in real time, or drive
# Chromium, tmux, gcc or a PostgreSQL server: ``--quick`` leaves them out (the rest runs in a few minutes).
PACED = ("test_tui", "test_capture", "test_multi_capture", "test_e2e", "test_factory", "test_instrument",
         "test_docs", "test_report", "test_pdf", "test_run", "test_demo", "test_firmware", "test_c_",
         "test_imu_link", "test_records", "test_turn_on", "test_characteris", "test_device_text",
         "test_contract", "test_hostile_text", "test_output_sets", "test_paced_port", "test_polled_port",
         "test_serial", "test_simulat", "test_table", "test_chamber", "test_supply", "test_mag_acquisition",
         "test_campaign_run")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--imu-port", default=None,
                     help="also run the device contract tests against this real serial port")
    parser.addoption("--chamber", default=None, metavar="URL",
                     help="also run the chamber contract tests against this real chamber "
                          "(votsch://HOST, espec:///dev/ttyUSB0, watlow-f4://PORT, binder://HOST)")
    parser.addoption("--supply", default=None, metavar="URL",
                     help="also run the supply contract test against this real bench supply (scpi://HOST, "
                          "korad:///dev/ttyUSB0); it sets at most 1 V and 50 mA and leaves the output off")
    parser.addoption("--quick", action="store_true",
                     help="leave out the tests that run a unit, an instrument or a factory run in real time "
                          "or drive Chromium, tmux, gcc or PostgreSQL (tests/conftest.py PACED)")
    parser.addoption("--table", default=None, metavar="URL",
                     help="also run the rate table contract test against this real table "
                          "(acutrol://HOST:PORT, aerosmith:///dev/ttyUSB0); it moves a few degrees")


@pytest.fixture(scope="session")
def reference_data() -> Path:
    """``tests/data``: real recordings made by others, with their licences (see its README.md)."""
    return REFERENCE_DATA


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not config.getoption("--quick"):
        return
    paced = [item for item in items if item.path.name.startswith(PACED)]
    if paced:
        config.hook.pytest_deselected(items=paced)
        items[:] = [item for item in items if not item.path.name.startswith(PACED)]
