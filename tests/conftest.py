"""Shared fixtures: where the reference recordings are, and the optional real port."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--imu-port", default=None,
                     help="also run the device contract tests against this real serial port")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (recordings made by others); tests using it skip where it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"reference recordings not found at {SHARED_DATA} (shared/ is not beside this checkout)")
    return SHARED_DATA
