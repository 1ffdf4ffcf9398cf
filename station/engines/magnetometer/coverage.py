"""Coverage of the sphere of field directions: which directions a magnetometer session visited.

A magnetometer fit is only as good as the spread of field directions it sees in the sensor's axes
(a hand-turned unit on a desk sees a band, not a sphere). The sphere is cut into ``N`` cells of
equal area by the recursive zonal equal-area partition (Leopardi 2006, "A partition of the unit
sphere into regions of equal area and small diameter", ETNA 25): two polar caps of one cell each,

    area of a cap = 4 pi sin^2(theta_c / 2) = 4 pi / N   =>   theta_c = 2 arcsin(sqrt(1 / N))   (1)

and between them collars of (ideal) angular width sqrt(4 pi / N), each cut into as many cells as
its area holds, the counts rounded so that the running total stays exact; each collar's bounding
colatitudes are then moved so that it holds exactly its cells' area,

    cos(theta_k) = 1 - 2 (cells in the caps and collars up to k) / N                           (2)

(the area of a cap of colatitude theta is 2 pi (1 - cos theta)). A direction falls in the collar
whose colatitudes bracket it and in the sector of that collar its longitude names. The share of
cells visited is the coverage; the cells not visited are named by a few of the 26 directions of
a cube (6 faces, 12 edges, 8 corners), each standing for the gaps within 45 deg of it: the words
an operator can act on.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

# Cells of the partition: 62 cells of about 26 deg across, fine enough to tell an operator which
# way to turn, coarse enough that a one-minute hand session can fill most of them.
CELLS = 62


@dataclass(frozen=True)
class _Partition:
    """Eq. (1)-(2): the colatitude boundaries of the zones (caps and collars) and their cell counts."""

    cos_edges: np.ndarray     # (zones + 1,) cos(theta) at the zone boundaries, 1 down to -1
    counts: np.ndarray        # (zones,) cells per zone
    first: np.ndarray         # (zones,) index of each zone's first cell


@lru_cache(maxsize=8)
def _partition(cells: int) -> _Partition:
    if cells < 2:
        raise ValueError(f"an equal-area partition needs at least 2 cells, got {cells}")
    area = 4.0 * np.pi / cells
    cap = 2.0 * np.arcsin(np.sqrt(1.0 / cells))                       # eq. (1)
    collars = max(int(round((np.pi - 2.0 * cap) / np.sqrt(area))), 0) if cells > 2 else 0
    ideal = np.zeros(collars)
    if collars:
        width = (np.pi - 2.0 * cap) / collars
        top = cap + width * np.arange(collars)
        # a collar's area over a cell's area: how many cells it ideally holds
        ideal = 2.0 * np.pi * (np.cos(top) - np.cos(top + width)) / area
    counts = [1]
    carried = 0.0
    for want in ideal:                                                 # rounding keeps the total exact
        n = int(round(want + carried))
        carried += want - n
        counts.append(n)
    counts.append(1)
    counts_arr = np.array(counts)
    counts_arr[-2 if collars else -1] += cells - counts_arr.sum()      # any rounding left over
    cos_edges = 1.0 - 2.0 * np.concatenate([[0], np.cumsum(counts_arr)]) / cells   # eq. (2)
    first = np.concatenate([[0], np.cumsum(counts_arr)[:-1]])
    return _Partition(cos_edges=cos_edges, counts=counts_arr, first=first)


def cell_index(directions: np.ndarray, cells: int = CELLS) -> np.ndarray:
    """The equal-area cell each direction falls in.

    Parameters
    ----------
    directions : ndarray, (n, 3)
        Vectors of any length (only their direction counts); rows with a zero or non-finite
        norm get index -1.
    cells : int
        Cells of the partition, eqs. (1)-(2).

    Returns
    -------
    ndarray of int, (n,)
        Cell index 0 .. cells-1 (cell 0 is the cap around +z), -1 where no direction.
    """
    v = np.asarray(directions, float).reshape(-1, 3)
    norm = np.linalg.norm(v, axis=1)
    ok = np.isfinite(norm) & (norm > 0)
    out = np.full(len(v), -1, dtype=np.int64)
    if not ok.any():
        return out
    part = _partition(cells)
    u = v[ok] / norm[ok, None]
    # zone by colatitude: cos_edges decreases, so search on its negation
    zone = np.searchsorted(-part.cos_edges, -np.clip(u[:, 2], -1.0, 1.0), side="right") - 1
    zone = np.clip(zone, 0, len(part.counts) - 1)
    lon = np.mod(np.arctan2(u[:, 1], u[:, 0]), 2.0 * np.pi)
    sector = np.minimum((lon / (2.0 * np.pi) * part.counts[zone]).astype(np.int64), part.counts[zone] - 1)
    out[ok] = part.first[zone] + sector
    return out


def cell_centres(cells: int = CELLS) -> np.ndarray:
    """Unit vector at the middle of every cell (mid-colatitude by area, mid-longitude of its sector).

    Parameters
    ----------
    cells : int
        Cells of the partition.

    Returns
    -------
    ndarray, (cells, 3)
        Row k is the centre of cell k; the caps' centres are the poles.
    """
    bounds = cell_bounds(cells)
    lon = 0.5 * (bounds[:, 0] + bounds[:, 1])
    z = 0.5 * (bounds[:, 2] + bounds[:, 3])
    z[[0, -1]] = np.sign(z[[0, -1]])                                   # a cap's centre is its pole
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    return np.column_stack([r * np.cos(lon), r * np.sin(lon), z])


def cell_bounds(cells: int = CELLS) -> np.ndarray:
    """Each cell's extent: longitude (rad, 0..2 pi) and z (cos colatitude) from and to.

    In the (longitude, z) plane, Lambert's cylindrical equal-area map, every cell is a rectangle of
    the same area, 4 pi / cells.

    Parameters
    ----------
    cells : int
        Cells of the partition.

    Returns
    -------
    ndarray, (cells, 4)
        Row k: [lon_from, lon_to, z_from, z_to] of cell k (z_from < z_to).
    """
    part = _partition(cells)
    out = np.empty((cells, 4))
    for zone, count in enumerate(part.counts):
        edges = np.arange(count + 1) * 2.0 * np.pi / count
        rows = slice(part.first[zone], part.first[zone] + count)
        out[rows] = np.column_stack([edges[:-1], edges[1:], np.full(count, part.cos_edges[zone + 1]),
                                     np.full(count, part.cos_edges[zone])])
    return out


def _cube_directions() -> tuple[np.ndarray, tuple[str, ...]]:
    """The 26 directions of a cube (faces, edges, corners) as unit vectors and as labels like ``+x-z``."""
    vectors, labels = [], []
    for sx in (-1, 0, 1):
        for sy in (-1, 0, 1):
            for sz in (-1, 0, 1):
                if sx == sy == sz == 0:
                    continue
                vectors.append(np.array([sx, sy, sz], float) / np.sqrt(sx * sx + sy * sy + sz * sz))
                signs = zip((sx, sy, sz), "xyz", strict=True)
                labels.append("".join(f"{'+' if s > 0 else '-'}{a}" for s, a in signs if s))
    # faces first, then edges, then corners: the simpler words win a tie
    order = sorted(range(len(labels)), key=lambda i: len(labels[i]))
    return np.array(vectors)[order], tuple(labels[i] for i in order)


_CUBE, _CUBE_LABELS = _cube_directions()
# Half-angle of the cone a cube direction names a gap for. Every direction is within 27.6 deg of
# one of the 26 (at worst the middle of a face-edge-corner triangle), so the cones cover the sphere
# and every missing cell gets a name.
_CONE_DEG = 45.0


def direction_label(direction: np.ndarray) -> str:
    """The nearest of the 26 cube directions to ``direction``, as ``+x``, ``-y+z`` or ``+x-y-z``.

    Parameters
    ----------
    direction : ndarray, (3,)
        A vector in the sensor's axes.

    Returns
    -------
    str
        The signed axes the direction is closest to.
    """
    return _CUBE_LABELS[int(np.argmax(_CUBE @ np.asarray(direction, float)))]


def advice(label: str) -> str:
    """What an operator does to make the field point along ``label`` in the sensor's axes.

    The Earth's field points toward magnetic north and, away from the equator, steeply down
    (north hemisphere) or up (south); in the middle latitudes it is closer to vertical than to
    horizontal. So "field along -z" means: the unit's -z axis toward magnetic north and down,
    that is roughly +z up; the text says both.

    Parameters
    ----------
    label : str
        A label of :func:`direction_label`.

    Returns
    -------
    str
        For example ``"field along -z: point the unit's -z axis along the field (north and, in the
        northern hemisphere, down), i.e. roughly +z up"``.
    """
    opposite = "".join(("-" if ch == "+" else "+" if ch == "-" else ch) for ch in label)
    return (f"field along {label}: point the unit's {label} axis along the field (toward magnetic north "
            f"and, in the northern hemisphere, down), i.e. roughly {opposite} up")


@dataclass(frozen=True)
class MagCoverage:
    """Which field directions a session visited (eqs. (1)-(2)).

    Attributes
    ----------
    share : float
        Visited cells over all cells, 0..1: the share of the sphere of directions covered.
    hit : ndarray of bool, (cells,)
        Cell k was visited by at least ``min_count`` directions.
    counts : ndarray of int, (cells,)
        Directions per cell.
    missing : tuple of str
        The directions not visited, named by cube directions (labels of :func:`direction_label`):
        greedily, the one whose 45-degree cone holds the most unvisited cells not yet named first.
    missing_share : tuple of float
        Per entry of ``missing``, the share of the sphere it stands for.
    """

    share: float
    hit: np.ndarray
    counts: np.ndarray
    missing: tuple[str, ...]
    missing_share: tuple[float, ...]

    def advice(self, limit: int = 3) -> list[str]:
        """What to do to fill the largest gaps: :func:`advice` for the first ``limit`` missing groups."""
        return [advice(label) for label in self.missing[:limit]]


def field_coverage(directions: np.ndarray, cells: int = CELLS, min_count: int = 1) -> MagCoverage:
    """Share of the sphere of field directions visited, on an equal-area grid (eqs. (1)-(2)).

    Parameters
    ----------
    directions : ndarray, (n, 3)
        Field vectors in the sensor's axes (any length: raw, hard-iron corrected or unit);
        rows with a zero or non-finite norm are ignored. For raw readings take the hard iron
        off first (``m - b``), or the directions are those seen from the wrong centre.
    cells : int
        Cells of the equal-area partition (default :data:`CELLS`).
    min_count : int
        Directions a cell needs to count as visited (1: any).

    Returns
    -------
    MagCoverage
        The share, the cells hit, their counts and the missing directions named.
    """
    index = cell_index(directions, cells)
    counts = np.bincount(index[index >= 0], minlength=cells)
    hit = counts >= max(int(min_count), 1)
    missing, shares = _name_gaps(cell_centres(cells)[~hit], cells)
    return MagCoverage(share=float(hit.mean()), hit=hit, counts=counts, missing=missing, missing_share=shares)


def _name_gaps(centres: np.ndarray, cells: int) -> tuple[tuple[str, ...], tuple[float, ...]]:
    """Name the missing cells with few cube directions: greedily, the direction whose cone is the
    most completely made of missing cells still unnamed, faces before edges before corners on a tie
    (so half a sphere missing reads ``-z`` first, not a corner)."""
    cos_cone = np.cos(np.radians(_CONE_DEG))
    near = (centres @ _CUBE.T) >= cos_cone                              # (missing, 26)
    cone_size = ((cell_centres(cells) @ _CUBE.T) >= cos_cone).sum(axis=0)
    left = np.ones(len(centres), bool)
    labels: list[str] = []
    shares: list[float] = []
    while left.any():
        gain = (near & left[:, None]).sum(axis=0)
        # lexsort: the last key is the first; argmax of the reversed order keeps the first on ties
        score = np.lexsort((-np.arange(len(gain)), gain / cone_size))
        best = int(score[-1])
        labels.append(_CUBE_LABELS[best])
        shares.append(float(gain[best]) / cells)
        left &= ~near[:, best]
    return tuple(labels), tuple(shares)
