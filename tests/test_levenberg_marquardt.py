"""The numpy port of MINPACK's lmder against scipy's (which runs MINPACK itself) and against known minima."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares

from station.engines.shared.levenberg_marquardt import least_squares_lm

T = np.linspace(0.0, 4.0, 60)
Y = 2.5 * np.exp(-1.3 * T) + 0.5 + 0.01 * np.random.default_rng(3).standard_normal(len(T))


def decay(p: np.ndarray) -> np.ndarray:
    return p[0] * np.exp(-p[1] * T) + p[2] - Y


def decay_jac(p: np.ndarray) -> np.ndarray:
    e = np.exp(-p[1] * T)
    return np.stack([e, -p[0] * T * e, np.ones_like(T)], axis=1)


def rosenbrock(x: np.ndarray) -> np.ndarray:
    return np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])


def rosenbrock_jac(x: np.ndarray) -> np.ndarray:
    return np.array([[-20.0 * x[0], 10.0], [-1.0, 0.0]])


@pytest.mark.parametrize("x0", [(1.0, 1.0, 0.0), (10.0, 0.1, 3.0), (0.5, 4.0, -1.0)])
def test_same_minimum_as_scipys_minpack(x0: tuple[float, ...]) -> None:
    ref = least_squares(decay, x0, jac=decay_jac, method="lm", x_scale="jac", ftol=1e-12, xtol=1e-12,
                        gtol=1e-12)
    got = least_squares_lm(decay, np.array(x0), decay_jac, ftol=1e-12, xtol=1e-12, gtol=1e-12)
    assert got.success
    # both stop at ftol, where rounding leaves the last iterates 1e-9 apart
    np.testing.assert_allclose(got.x, ref.x, rtol=1e-8)
    assert got.cost == pytest.approx(ref.cost, rel=1e-12)
    # the same iterations to within one evaluation: the step for a given lambda is MINPACK's
    assert abs(got.nfev - ref.nfev) <= 2


@pytest.mark.parametrize("x0", [(-1.2, 1.0), (3.0, -4.0), (0.0, 0.0)])
def test_rosenbrock_reaches_its_zero(x0: tuple[float, float]) -> None:
    got = least_squares_lm(rosenbrock, np.array(x0), rosenbrock_jac, ftol=1e-14, xtol=1e-14, gtol=1e-14)
    np.testing.assert_allclose(got.x, [1.0, 1.0], atol=1e-10)
    assert got.cost < 1e-20


def test_rank_deficient_jacobian_and_evaluation_budget() -> None:
    # the third parameter does not enter: its column is zero, the others are fitted as usual
    def fun(p: np.ndarray) -> np.ndarray:
        return decay(np.array([p[0], p[1], 0.5]))

    def jac(p: np.ndarray) -> np.ndarray:
        j = decay_jac(np.array([p[0], p[1], 0.5]))
        j[:, 2] = 0.0
        return j

    got = least_squares_lm(fun, np.array([1.0, 1.0, 7.0]), jac, ftol=1e-12, xtol=1e-12, gtol=1e-12)
    assert got.x[2] == 7.0
    np.testing.assert_allclose(got.x[:2], [2.5, 1.3], rtol=0.02)
    short = least_squares_lm(decay, np.array([10.0, 0.1, 3.0]), decay_jac, ftol=1e-15, xtol=1e-15, gtol=0.0,
                             max_nfev=3)
    assert short.status == 5 and not short.success and short.nfev == 3 and "max_nfev" in short.message


def test_too_few_residuals_are_refused() -> None:
    with pytest.raises(ValueError, match="at least as many"):
        least_squares_lm(lambda p: p[:1], np.zeros(2), lambda p: np.eye(2)[:1])
