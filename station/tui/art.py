"""Text drawings of what the operator must do: which face of the unit is up, and which way to turn."""

from __future__ import annotations

import math

from station.acquisition.sequences import PoseStep, RotationStep, Step, pose_vector

AXES = "XYZ"


def _faces(label: str) -> tuple[str, str]:
    """(up faces, down faces) of a pose label, e.g. "+x+y" -> ("+X +Y", "-X -Y")."""
    v = pose_vector(label)
    up = [("+" if v[i] > 0 else "-") + AXES[i] for i in range(3) if v[i]]
    down = [("-" if v[i] > 0 else "+") + AXES[i] for i in range(3) if v[i]]
    return " ".join(up), " ".join(down)


def pose_art(label: str) -> str:
    """A box with the face(s) to turn up written on its top, the one(s) on the table below it."""
    up, down = _faces(label)
    n = len(up.split())
    how = {1: "face up, lying flat", 2: "edge up: tilt 45 deg between the two faces",
           3: "corner up: balance on the opposite corner"}[n]
    top = f"{up:^11}"
    return "\n".join([
        "              ▲ up",
        "       ┌─────────────┐",
        f"      ╱ {top} ╱│",
        "     ╱    (top)    ╱ │",
        "    ┌─────────────┐  │",
        "    │             │  ┘",
        "    │     IMU     │ ╱",
        "    └─────────────┘╱",
        "    ▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀ table",
        f"  {up} {how}",
        f"  ({down} towards the table)",
    ])


def rotation_art(step: RotationStep) -> str:
    """The vertical axis with a curved arrow: counter-clockwise seen from above is positive."""
    axis = AXES[step.axis]
    angle = step.angle_deg
    ccw = angle > 0
    arrow_top = "◀──" if ccw else "──▶"
    arrow_bottom = "──▶" if ccw else "◀──"
    sense = "counter-clockwise" if ccw else "clockwise"
    turns = abs(angle) / 360.0
    amount = f"{abs(angle):.0f} deg" + (f" ({turns:g} turn{'s' if turns != 1 else ''})"
                                         if math.isclose(turns % 1, 0) else "")
    return "\n".join([
        f"             +{axis} up",
        "              ▲",
        f"        ╭─{arrow_top}─┼─────╮",
        "       ╱      │      ╲",
        "      │       │       │",
        "       ╲      │      ╱",
        f"        ╰─────┼─{arrow_bottom}─╯",
        "              │",
        f"  turn {'+' if ccw else '-'}{amount} about +{axis}, {sense} seen from above,",
        f"  at about {step.rate_dps:.0f} deg/s, then hold still",
    ])


def step_art(step: Step) -> str:
    """The drawing for a step: the unit in its pose, or the turn to make."""
    return pose_art(step.label) if isinstance(step, PoseStep) else rotation_art(step)


def step_instruction(step: Step) -> str:
    """One sentence the operator reads first."""
    if isinstance(step, PoseStep):
        up, _ = _faces(step.label)
        return f"Place the unit with {up} up and keep it still for {step.hold_s:g} s."
    return (f"Stand the unit with +{AXES[step.axis]} up, keep it still, then turn it "
            f"{step.angle_deg:+.0f} deg about +{AXES[step.axis]} when asked.")


def bar(fraction: float, width: int = 30, full: str = "█", empty: str = "░") -> str:
    """A text bar of ``fraction`` (clipped to 0..1) with eighth-block resolution."""
    fraction = min(1.0, max(0.0, fraction if math.isfinite(fraction) else 0.0))
    eighths = round(fraction * width * 8)
    whole, part = divmod(eighths, 8)
    partial = " ▏▎▍▌▋▊▉"[part].strip() if part else ""
    body = full * whole + partial
    return body + empty * (width - len(body))
