"""An Ideal Aerosmith rate table emulator: CR-ended ASCII, one axis.

The strings are those of ``shared/specs/instruments.md`` ("Rate tables"): ``HOM`` homes,
``P<deg>`` moves to a position, ``JOG <deg/s>`` turns at a rate, ``STO`` stops, ``PPO?`` reads
the position (the only query, answered with one number), ``SRV 1`` / ``SRV 0`` servo on and off,
``ACL <deg/s^2>`` the acceleration. Nothing else is answered. The servo is on at power-up, so a
host that never sends ``SRV 1`` (the station's generic table does not) still moves the table.

The motion and the coupling to the simulated unit are :class:`~mocks.instruments.acutrol.TableAxis`'s.
"""

from __future__ import annotations

import math
import re

from mocks.instruments.acutrol import TableEmulator

_NUMBER = r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*"


class AerosmithEmulator(TableEmulator):
    """An Aerosmith controller: ``AerosmithEmulator(device=sim, mount="+z").serve("pty")``."""

    END = b"\r"

    def handle(self, line: str) -> str | None:
        """One Aerosmith line; ``PPO?``'s position, else None."""
        axis = self.axes[0]
        text = line.strip().upper()
        if text == "PPO?":
            return f"{axis.state()[0]:.4f}"
        if text == "HOM":
            axis.move_to(0.0)
        elif text == "STO":
            axis.stop()
        elif text in ("SRV 1", "SRV 0"):
            axis.set_servo(text.endswith("1"))
        elif (match := re.fullmatch(r"(P|JOG|ACL)" + _NUMBER, text)) is not None:
            value = float(match.group(2))
            if not math.isfinite(value):
                return None
            if match.group(1) == "P":
                axis.move_to(value)
            elif match.group(1) == "JOG":
                axis.turn(value)
            else:
                axis.set_acceleration(value)
        return None
