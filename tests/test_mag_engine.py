"""Magnetometer engine: coverage of the sphere of field directions."""

from __future__ import annotations

import numpy as np

from station.engines.mag_coverage import CELLS, cell_centres, cell_index, field_coverage


def _uniform(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def test_cells_have_equal_area() -> None:
    # uniform directions fill every cell alike: counts within 5 sigma of the binomial spread
    n = 124_000
    counts = np.bincount(cell_index(_uniform(n)), minlength=CELLS)
    mean = n / CELLS
    assert np.all(np.abs(counts - mean) < 5 * np.sqrt(mean))
    # and each centre lies in its own cell
    assert np.array_equal(cell_index(cell_centres()), np.arange(CELLS))


def test_full_sphere_is_covered_and_half_names_the_missing_side() -> None:
    u = _uniform(20_000)
    assert field_coverage(u * 48.0).share == 1.0
    assert field_coverage(u).missing == ()
    half = field_coverage(u[u[:, 2] > 0])
    assert half.share == 0.5
    assert half.missing[0] == "-z"
    assert abs(sum(half.missing_share) - 0.5) < 1e-12
    assert "roughly +z up" in half.advice(1)[0]


def test_no_usable_direction_covers_nothing() -> None:
    cov = field_coverage(np.array([[0.0, 0.0, 0.0], [np.nan, 1.0, 0.0]]))
    assert cov.share == 0.0
    assert not cov.hit.any()
    assert set(cov.missing) >= {"+x", "-x", "+y", "-y", "+z", "-z"}


def test_min_count_leaves_out_sparse_cells() -> None:
    u = _uniform(200, seed=1)
    assert field_coverage(u, min_count=1).share > field_coverage(u, min_count=5).share
