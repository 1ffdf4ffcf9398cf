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


def _flat(up: str) -> list[str]:
    top = f"{up:^11}"
    return [
        "              ▲ up",
        "       ┌─────────────┐",
        f"      ╱ {top} ╱│",
        "     ╱    (top)    ╱ │",
        "    ┌─────────────┐  │",
        "    │             │  ┘",
        "    │     IMU     │ ╱",
        "    └─────────────┘╱",
        "    ▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀ table",
    ]


def _edge(up: str) -> list[str]:
    # Tilted 45 deg onto an edge: the two faces up are the two upper slopes, left and right.
    left, right = up.split()
    return [
        "              ▲ up",
        "             ╱ ╲",
        f"      {left:>5} ╱   ╲ {right}",
        "           ╱ IMU ╲",
        "           ╲     ╱",
        "            ╲   ╱",
        "             ╲ ╱",
        "    ▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀ table",
    ]


def _corner(up: str) -> list[str]:
    # Balanced on a corner: the cube seen along its diagonal, three faces up.
    a, b, c = up.split()
    return [
        "              ▲ up",
        "             ╱ ╲",
        f"         ╱ {c:^7} ╲",
        "      │╲             ╱│",
        "      │   ╲       ╱   │",
        f"      │{a:^6}╲ ╱{b:^6}│",
        "       ╲      │      ╱",
        "          ╲   │   ╱",
        "             ╲│╱",
        "    ▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀▀ table",
    ]


def pose_drawing(label: str) -> list[str]:
    """The unit in its pose: flat with the face up written on top, tilted onto an edge (two faces
    up, drawn as a diamond), or on a corner (three faces up).

    Parameters
    ----------
    label : str
        The pose, e.g. ``-z`` or ``+x+y``.

    Returns
    -------
    list of str
        The drawing's lines.
    """
    up, _ = _faces(label)
    return {1: _flat, 2: _edge, 3: _corner}[len(up.split())](up)


def pose_caption(label: str) -> list[str]:
    """What the drawing shows, in words: the face(s) up and the one(s) towards the table.

    Parameters
    ----------
    label : str
        The pose.

    Returns
    -------
    list of str
        Two lines.
    """
    up, down = _faces(label)
    # Short enough for the step panel at 80 columns (40 characters).
    how = {1: "face up, lying flat", 2: "edge up: tilted 45 deg", 3: "corner up, balanced"}[len(up.split())]
    return [f"{up} {how}", f"({down} towards the table)"]


def pose_art(label: str) -> str:
    """The drawing of the pose with its caption below (:func:`pose_drawing`, :func:`pose_caption`)."""
    return "\n".join(pose_drawing(label) + [f"  {line}" for line in pose_caption(label)])


def rotation_drawing(step: RotationStep) -> list[str]:
    """The vertical axis with a curved arrow: counter-clockwise seen from above is positive.

    Parameters
    ----------
    step : RotationStep
        The turn.

    Returns
    -------
    list of str
        The drawing's lines.
    """
    axis = AXES[step.axis]
    ccw = step.angle_deg > 0
    arrow_top = "◀──" if ccw else "──▶"
    arrow_bottom = "──▶" if ccw else "◀──"
    return [
        f"             +{axis} up",
        "              ▲",
        f"        ╭─{arrow_top}─┼─────╮",
        "       ╱      │      ╲",
        "      │       │       │",
        "       ╲      │      ╱",
        f"        ╰─────┼─{arrow_bottom}─╯",
        "              │",
    ]


def rotation_caption(step: RotationStep) -> list[str]:
    """The turn in words: angle, axis, direction seen from above, rate.

    Parameters
    ----------
    step : RotationStep
        The turn.

    Returns
    -------
    list of str
        Two lines.
    """
    axis = AXES[step.axis]
    angle = step.angle_deg
    ccw = angle > 0
    turns = abs(angle) / 360.0
    amount = f"{abs(angle):.0f} deg" + (f" ({turns:g} turn{'s' if turns != 1 else ''})"
                                         if math.isclose(turns % 1, 0) else "")
    sense = "counter-clockwise" if ccw else "clockwise"
    return [f"turn {'+' if ccw else '-'}{amount} about +{axis}, {sense} seen from above,",
            f"at about {step.rate_dps:.0f} deg/s, then hold still"]


def rotation_art(step: RotationStep) -> str:
    """The drawing of the turn with its caption below."""
    return "\n".join(rotation_drawing(step) + [f"  {line}" for line in rotation_caption(step)])


def step_art(step: Step) -> str:
    """The drawing for a step: the unit in its pose, or the turn to make."""
    return pose_art(step.label) if isinstance(step, PoseStep) else rotation_art(step)


def step_caption(step: Step) -> list[str]:
    """The caption of a step's drawing (:func:`pose_caption` or :func:`rotation_caption`)."""
    return pose_caption(step.label) if isinstance(step, PoseStep) else rotation_caption(step)


def step_drawing(step: Step) -> list[str]:
    """The drawing of a step without its caption."""
    return pose_drawing(step.label) if isinstance(step, PoseStep) else rotation_drawing(step)


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
