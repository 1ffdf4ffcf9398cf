"""The simulated unit: truth model, rig, fault injection, and the ways to serve it.

- :mod:`mocks.truth` and :mod:`mocks.rig`: ``simulate(truth, segments)`` -> arrays (no I/O);
- :mod:`mocks.device`: the device state machine speaking the native protocol;
- :mod:`mocks.pty_server`: the device on a pseudo-terminal (``imu-station simulate``);
- :mod:`mocks.protocol_sim`: the device in-process as a ``sim://`` pyserial URL.
"""

from __future__ import annotations


def register_sim_url() -> None:
    """Let ``serial.serial_for_url("sim://...")`` find :mod:`mocks.protocol_sim` (idempotent)."""
    import serial

    if "mocks" not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append("mocks")
