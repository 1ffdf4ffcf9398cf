"""The sphere of field directions drawn in the terminal: its two halves, +z and -z, side by side.

Each half is a disc of text cells in Lambert's azimuthal equal-area projection, so equal areas of
the sphere take equal numbers of cells: a cell at (x, y) of the unit disc (r^2 = x^2 + y^2 <= 1)
stands for the direction

    z = +-(1 - r^2),   (x, y) * sqrt(1 - z^2) / r                                          (1)

(r = sqrt(2) sin(theta / 2) scaled to 1 at the rim, theta the angle from the half's pole). Both
halves are drawn as seen from +z, +x to the right and +y up, so a direction near the rim is at the
same place in both. A text cell is about twice as tall as it is wide: a disc of ``rows`` rows is
``2 rows + 1`` columns wide. Cells the session visited are filled, the others dotted, and the
direction the field has now is marked.
"""

from __future__ import annotations

import numpy as np
from rich.text import Text

from station.engines.magnetometer.coverage import cell_index

VISITED, MISSING, NOW = "█", "·", "◆"


def disc_directions(rows: int, lower: bool) -> np.ndarray:
    """The direction each text cell of a half's disc stands for, eq. (1); NaN outside the disc.

    Parameters
    ----------
    rows : int
        Rows of the disc (odd draws a centre row).
    lower : bool
        The -z half (else +z).

    Returns
    -------
    ndarray, (rows, 2 * rows + 1, 3)
        Unit vectors; NaN where the cell lies outside the disc.
    """
    cols = 2 * rows + 1
    y = 1.0 - (np.arange(rows) + 0.5) * 2.0 / rows                 # top row is +y
    x = -1.0 + (np.arange(cols) + 0.5) * 2.0 / cols
    xx, yy = np.meshgrid(x, y)
    r2 = xx**2 + yy**2
    z = 1.0 - r2
    scale = np.sqrt(np.clip(1.0 - z**2, 0.0, None)) / np.sqrt(np.where(r2 > 0, r2, 1.0))
    out = np.stack([xx * scale, yy * scale, -z if lower else z], axis=-1)
    out[r2 > 1.0] = np.nan
    return out


def _marker(directions: np.ndarray, lower: bool, now: np.ndarray | None) -> tuple[int, int] | None:
    """The text cell of the half nearest to the direction ``now``, when ``now`` lies in that half."""
    if now is None or not np.isfinite(now).all() or not np.linalg.norm(now) or (now[2] < 0) != lower:
        return None
    cos = np.einsum("rck,k->rc", np.nan_to_num(directions), now / np.linalg.norm(now))
    cos[~np.isfinite(directions[..., 0])] = -np.inf  # outside the disc
    best = np.unravel_index(int(np.argmax(cos)), cos.shape)
    return int(best[0]), int(best[1])


def hemispheres(hit: np.ndarray, now: np.ndarray | None = None, rows: int = 7) -> Text:
    """Both halves of the sphere of directions: visited cells filled, the others dotted.

    Parameters
    ----------
    hit : ndarray of bool, (cells,)
        Which cells of the coverage partition were visited (``MagCoverage.hit``).
    now : ndarray, (3,), optional
        The field's direction now (sensor axes), marked with a diamond.
    rows : int
        Rows of each disc.

    Returns
    -------
    rich.text.Text
        A title row, the two discs side by side, and a row naming the axes.
    """
    halves = [disc_directions(rows, lower) for lower in (False, True)]
    width = halves[0].shape[1]
    text = Text()
    text.append(f"{'+z half':^{width}}   {'-z half':^{width}}\n", style="bold")
    cells = [cell_index(h.reshape(-1, 3), len(hit)).reshape(h.shape[:2]) for h in halves]
    marks = [_marker(h, lower, now) for h, lower in zip(halves, (False, True), strict=True)]
    for r in range(rows):
        for k, (half, index) in enumerate(zip(halves, cells, strict=True)):
            if k:
                text.append("   ")
            for c in range(width):
                if marks[k] == (r, c):
                    text.append(NOW, style="bold yellow")
                elif not np.isfinite(half[r, c, 0]):
                    text.append(" ")
                elif index[r, c] >= 0 and hit[index[r, c]]:
                    text.append(VISITED, style="green")
                else:
                    text.append(MISSING, style="dim")
        text.append("\n")
    text.append(f"{'+y up, +x right':^{2 * width + 3}}", style="dim")
    return text
