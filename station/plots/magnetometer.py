"""``--plot`` of ``imu-station calibrate --method mag``: coverage, the corrected sphere, the residual."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from station.common.files import atomic_open
from station.engines.magnetometer.calibration import MagCalibration
from station.engines.magnetometer.coverage import CELLS, cell_bounds

# Points drawn at the most per panel: enough to show the shape, few enough for a light PNG.
MAX_POINTS = 4000


def plot_mag(cal: MagCalibration, t: np.ndarray, mag: np.ndarray, path: str | Path, title: str) -> None:
    """Write a PNG of a magnetometer fit.

    Left: the sphere of field directions in Lambert's cylindrical equal-area map, longitude
    against the z component, where every cell of the coverage grid is a rectangle of the same
    area, blue where visited, orange where not (the gaps the warning names), and the samples'
    directions dotted. Middle: the corrected field C (m - b) in 3-D against a sphere of radius F.
    Right: |C (m - b)| - F against time, the disturbed stretches left out shaded.

    Parameters
    ----------
    cal : MagCalibration
        The fit.
    t : ndarray, (N,)
        Sample times, s.
    mag : ndarray, (N, 3)
        Raw field, microtesla (NaN rows skipped).
    path : str or Path
        The PNG to write (atomically).
    title : str
        The figure's title.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    rows = np.isfinite(mag).all(axis=1)
    t, mag = np.asarray(t, float)[rows], np.asarray(mag, float)[rows]
    h = (mag - cal.bias) @ cal.correction.T
    step = max(1, len(h) // MAX_POINTS)
    u = h / np.linalg.norm(h, axis=1)[:, None]
    fig = plt.figure(figsize=(15, 4.8))
    ax = fig.add_subplot(1, 3, 1)
    for (lon0, lon1, z0, z1), hit in zip(cell_bounds(CELLS), cal.coverage.hit, strict=True):
        ax.add_patch(Rectangle((np.degrees(lon0), z0), np.degrees(lon1 - lon0), z1 - z0,
                               facecolor="#9ecae1" if hit else "#fdd0a2", edgecolor="white", lw=1.0))
    lon = np.degrees(np.mod(np.arctan2(u[::step, 1], u[::step, 0]), 2 * np.pi))
    ax.scatter(lon, u[::step, 2], s=2, c="k")
    ax.set_xlim(0, 360)
    ax.set_ylim(-1.0, 1.0)
    ax.set_xlabel("longitude of the direction about z (deg)")
    ax.set_ylabel("z component (equal area)")
    ax.set_title(f"coverage {cal.coverage.share:.0%}: visited (blue), missing (orange)")
    ax3 = fig.add_subplot(1, 3, 2, projection="3d")
    a, b = np.meshgrid(np.linspace(0, 2 * np.pi, 25), np.linspace(0, np.pi, 13))
    f = cal.field_norm
    ax3.plot_wireframe(f * np.cos(a) * np.sin(b), f * np.sin(a) * np.sin(b), f * np.cos(b), color="0.8",
                       lw=0.4)
    ax3.scatter(h[::step, 0], h[::step, 1], h[::step, 2], s=1, c="tab:blue")
    ax3.set_title(f"corrected field (frame {cal.frame}), sphere of {f:.1f} uT")
    ax3.set_box_aspect((1, 1, 1))
    axr = fig.add_subplot(1, 3, 3)
    axr.plot(t[::step], np.linalg.norm(h[::step], axis=1) - f, lw=0.6)
    for d in cal.disturbances:
        axr.axvspan(d.t0, d.t1, color="tab:red", alpha=0.2)
    axr.axhline(0, color="k", lw=0.5)
    axr.set_xlabel("t (s)")
    axr.set_ylabel("|true| - F (uT)")
    axr.set_title(f"residual {cal.residual_rms:.3g} uT RMS; red: left out")
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=100)
    plt.close(fig)
