"""Levenberg-Marquardt for small dense least-squares problems: MINPACK's ``lmder`` in numpy.

The calibration fits have at most a dozen parameters and a few hundred residuals; scipy's
``least_squares(method="lm")`` runs MINPACK's ``lmder`` on them, but importing ``scipy.optimize`` costs a
command more than the fit itself (0.3 s of start-up against about 0.05 s of fitting). This module follows
``lmder`` step by step (J. J. More, B. S. Garbow, K. E. Hillstrom, "User guide for MINPACK-1", Argonne
ANL-80-74, 1980, chapter 2 and the ``lmder``/``lmpar`` sources; J. J. More, "The Levenberg-Marquardt
algorithm: implementation and theory", Lecture Notes in Mathematics 630, 1978):

- the scaling ``D`` is the column norms of the Jacobian, never decreasing (``mode = 1``, scipy's
  ``x_scale="jac"``), the first trust radius ``Delta = factor ||D x||`` (``factor = 100``);
- each step solves ``min ||J p + f||^2 + lambda ||D p||^2`` with ``lambda`` such that
  ``| ||D p|| - Delta | <= 0.1 Delta`` (More 1978, sec. 5: the Hebden-More iteration on
  ``phi(lambda) = ||D p(lambda)|| - Delta`` with the bounds ``l <= lambda <= u`` of ``lmpar``),
  here on the singular value decomposition of ``J D^-1`` rather than MINPACK's QR factors: for a given
  ``lambda`` the step is the same, only rounding differs;
- the ratio of actual to predicted reduction updates ``Delta`` and ``lambda`` as ``lmder`` does, a step
  is taken when the ratio is at least 1e-4, and the stopping tests are ``lmder``'s ``ftol``, ``xtol`` and
  ``gtol`` ones (info 1 to 8).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

EPS = float(np.finfo(float).eps)
DWARF = float(np.finfo(float).tiny)
FACTOR = 100.0  # lmder's initial step bound factor (scipy passes 100)
MESSAGES = {
    1: "both actual and predicted relative reductions in the sum of squares are at most ftol",
    2: "relative error between two consecutive iterates is at most xtol",
    3: "both actual and predicted relative reductions are at most ftol and the relative error between two "
       "consecutive iterates is at most xtol",
    4: "the cosine of the angle between the residuals and any column of the Jacobian is at most gtol",
    5: "the number of residual evaluations reached max_nfev",
    6: "ftol is too small: no further reduction in the sum of squares is possible",
    7: "xtol is too small: no further improvement in the approximate solution is possible",
    8: "gtol is too small: the residuals are orthogonal to the columns of the Jacobian to machine precision",
}


@dataclass
class LsqResult:
    """What :func:`least_squares_lm` found: ``x``, the residuals ``fun`` there, ``cost = 1/2 ||fun||^2``."""

    x: np.ndarray
    fun: np.ndarray
    cost: float
    nfev: int
    njev: int
    status: int

    @property
    def success(self) -> bool:
        """True when a convergence test (status 1 to 4) stopped the iteration."""
        return 1 <= self.status <= 4

    @property
    def message(self) -> str:
        """The stopping reason in words."""
        return MESSAGES[self.status]


def _step(s: np.ndarray, vt: np.ndarray, g: np.ndarray, diag: np.ndarray, lam: float) -> tuple[np.ndarray,
                                                                                              np.ndarray]:
    """The scaled step ``z = D p(lambda)`` in the right singular basis and ``p`` itself (More 1978, eq. 5.2
    with ``J D^-1 = U S V^T``, ``g = U^T f``): ``V^T z = -s g / (s^2 + lambda)``."""
    zv = -s * g / (s * s + lam)
    return zv, (vt.T @ zv) / diag


def _lm_parameter(s: np.ndarray, vt: np.ndarray, g: np.ndarray, diag: np.ndarray, delta: float,
                  lam: float) -> tuple[float, np.ndarray]:
    """``lmpar``: lambda with ``||D p|| - Delta`` within 0.1 Delta (or 0 for a Gauss-Newton step inside
    1.1 Delta), from the starting value ``lam``; returns lambda and the step p."""
    rank = int(np.count_nonzero(s > s[0] * len(diag) * EPS)) if len(s) and s[0] > 0 else 0
    s, vt, g = s[:rank], vt[:rank], g[:rank]
    zv, p = _step(s, vt, g, diag, 0.0)
    dxnorm = float(np.linalg.norm(zv))
    fp = dxnorm - delta
    if fp <= 0.1 * delta:
        return 0.0, p
    n = len(diag)

    def newton(zv: np.ndarray, lam: float, dxnorm: float) -> float:
        # lmpar's correction (fp / delta) / ||R_lambda^-T D (D p) / ||D p||||^2 in the singular basis
        return float(fp / delta / (np.sum(zv * zv / (s * s + lam)) / (dxnorm * dxnorm)))

    low = newton(zv, 0.0, dxnorm) if rank == n else 0.0
    gnorm = float(np.linalg.norm(s * g))
    high = gnorm / delta if gnorm > 0 else DWARF / min(delta, 0.1)
    lam = min(max(lam, low), high)
    if lam == 0.0:
        lam = gnorm / dxnorm
    for iteration in range(1, 11):
        if lam == 0.0:
            lam = max(DWARF, 0.001 * high)
        zv, p = _step(s, vt, g, diag, lam)
        dxnorm = float(np.linalg.norm(zv))
        previous, fp = fp, dxnorm - delta
        if abs(fp) <= 0.1 * delta or (low == 0.0 and fp <= previous < 0.0) or iteration == 10:
            break
        correction = newton(zv, lam, dxnorm)
        if fp > 0.0:
            low = max(low, lam)
        elif fp < 0.0:
            high = min(high, lam)
        lam = max(low, lam + correction)
    return lam, p


def least_squares_lm(fun: Callable[..., np.ndarray], x0: np.ndarray, jac: Callable[..., np.ndarray],
                     args: tuple = (), ftol: float = 1e-8, xtol: float = 1e-8, gtol: float = 1e-8,
                     max_nfev: int | None = None) -> LsqResult:
    """Minimise ``1/2 ||fun(x)||^2`` by MINPACK's ``lmder`` (module docstring) with Jacobian ``jac``.

    The same options and results as ``scipy.optimize.least_squares(fun, x0, jac, method="lm",
    x_scale="jac", ...)``.

    Parameters
    ----------
    fun : callable
        ``fun(x, *args)`` -> residuals (m,), m >= n.
    x0 : ndarray, (n,)
        Start.
    jac : callable
        ``jac(x, *args)`` -> (m, n).
    args : tuple
        Extra arguments of both.
    ftol, xtol, gtol : float
        lmder's tolerances: relative reduction of the sum of squares, relative change of ``D x``, and the
        largest cosine between the residuals and a column of the Jacobian.
    max_nfev : int, optional
        Most residual evaluations (default ``100 n``, as scipy's).

    Returns
    -------
    LsqResult
    """
    x = np.array(x0, dtype=float).ravel()
    n = len(x)
    max_nfev = 100 * n if max_nfev is None else max_nfev
    f = np.asarray(fun(x, *args), dtype=float)
    if len(f) < n:
        raise ValueError(f"{len(f)} residuals for {n} parameters: the method needs at least as many")
    nfev, njev = 1, 0
    fnorm = float(np.linalg.norm(f))
    lam = 0.0
    delta = xnorm = 0.0
    diag = np.ones(n)
    status = 0
    first = True
    while status == 0:
        j = np.asarray(jac(x, *args), dtype=float)
        njev += 1
        acnorm = np.linalg.norm(j, axis=0)
        if first:
            diag = np.where(acnorm == 0.0, 1.0, acnorm)
            xnorm = float(np.linalg.norm(diag * x))
            delta = FACTOR * xnorm if xnorm != 0.0 else FACTOR
        jtf = j.T @ f
        nonzero = acnorm != 0.0
        gnorm = float(np.max(np.abs(jtf[nonzero]) / (fnorm * acnorm[nonzero]), initial=0.0)) if fnorm else 0.0
        if gnorm <= gtol:
            status = 4
            break
        diag = np.maximum(diag, acnorm)
        _, s, vt = np.linalg.svd(j / diag, full_matrices=False)
        # U^T f without forming U: S U^T f = V^T (J D^-1)^T f
        g = (vt @ (jtf / diag)) / np.where(s > 0, s, 1.0)
        while True:
            lam, p = _lm_parameter(s, vt, g, diag, delta, lam)
            pnorm = float(np.linalg.norm(diag * p))
            if first:
                delta = min(delta, pnorm)
            x_new = x + p
            f_new = np.asarray(fun(x_new, *args), dtype=float)
            nfev += 1
            fnorm_new = float(np.linalg.norm(f_new))
            actred = 1.0 - (fnorm_new / fnorm) ** 2 if 0.1 * fnorm_new < fnorm else -1.0
            t1 = float(np.linalg.norm(j @ p)) / fnorm
            t2 = np.sqrt(lam) * pnorm / fnorm
            prered = t1 * t1 + 2.0 * t2 * t2
            dirder = -(t1 * t1 + t2 * t2)
            ratio = actred / prered if prered != 0.0 else 0.0
            if ratio <= 0.25:
                temp = 0.5 if actred >= 0.0 else 0.5 * dirder / (dirder + 0.5 * actred)
                if 0.1 * fnorm_new >= fnorm or temp < 0.1:
                    temp = 0.1
                delta = temp * min(delta, pnorm / 0.1)
                lam /= temp
            elif lam == 0.0 or ratio >= 0.75:
                delta = pnorm / 0.5
                lam *= 0.5
            if ratio >= 1e-4:
                x, f, fnorm = x_new, f_new, fnorm_new
                xnorm = float(np.linalg.norm(diag * x))
                first = False
            if abs(actred) <= ftol and prered <= ftol and 0.5 * ratio <= 1.0:
                status = 1
            if delta <= xtol * xnorm:
                status = 3 if status == 1 else 2
            if status == 0:
                if nfev >= max_nfev:
                    status = 5
                elif abs(actred) <= EPS and prered <= EPS and 0.5 * ratio <= 1.0:
                    status = 6
                elif delta <= EPS * xnorm:
                    status = 7
                elif gnorm <= EPS:
                    status = 8
            if status or ratio >= 1e-4:
                break
    return LsqResult(x, f, 0.5 * fnorm * fnorm, nfev, njev, status)
