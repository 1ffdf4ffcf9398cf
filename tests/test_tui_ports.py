"""The connect screen lists the serial ports with what pyserial knows of them (drivers.ports, as
``imu-station ports``)."""

from __future__ import annotations

import asyncio

import pytest
from serial.tools import list_ports
from serial.tools.list_ports_common import ListPortInfo
from tui_helpers import screen_text, wait_for

from station.tui.app import StationApp
from station.tui.config import TuiConfig

pytestmark = pytest.mark.timeout(60)


def _ports() -> list[ListPortInfo]:
    usb = ListPortInfo("/dev/ttyUSB0", skip_link_detection=True)
    usb.description, usb.manufacturer = "CP2102 USB to UART Bridge", "Silicon Labs"
    usb.product = "CP2102 USB to UART"  # within the description: not repeated
    usb.serial_number, usb.vid, usb.pid, usb.location = "0001", 0x10C4, 0xEA60, "1-1.2:1.0"
    usb.hwid = "USB VID:PID=10C4:EA60 SER=0001 LOCATION=1-1.2:1.0"
    plain = ListPortInfo("/dev/ttyS0", skip_link_detection=True)  # description "n/a": nothing known
    return [usb, plain]


def test_the_connect_screen_lists_them_at_80_columns(monkeypatch):
    monkeypatch.setattr(list_ports, "comports", _ports)
    app = StationApp(TuiConfig())

    async def run() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await wait_for(pilot, lambda: type(app.screen).__name__ == "ConnectScreen", 5, "connect")
            await pilot.pause(0.2)
            text = screen_text(app)
            assert "/dev/ttyUSB0         CP2102 USB to UART Bridge" in text
            assert "Silicon Labs, SN 0001" in text and "10C4:EA60" in text and "simulated unit" in text
            assert "/dev/ttyS0" in text and "n/a" not in text
            app.exit(0)

    asyncio.run(run())
