"""The trust-region solve of one candidate model (eq. (1) of :mod:`station.engines.allan.model`), compiled.

This is scipy's ``least_squares(method="trf", tr_solver="exact", x_scale=1.0, loss="linear")`` with bounds
(``scipy/optimize/_lsq/trf.py``, ``trf_bounds``, and its helpers of ``common.py``, scipy 1.17: Branch,
Coleman and Li's trust-region reflective method, the step from one SVD of the augmented Jacobian and Moré's
iteration on the Levenberg-Marquardt parameter), step for step, with the candidate's residuals and
Jacobian (:func:`station.engines.allan._wavelet_moments._solve`: exact in the log coefficients, central
differences in the log time constants) in the same compiled code. The model selection fits some 40 to 60
candidates of at most 53 points an axis; with scipy each solve spent about 4 ms in the interpreter's
small-array steps, and rebuilt the candidate's columns in Python at every evaluation. numba compiles this
module on first use (cached on disk beside it, as :mod:`station.engines.allan._kernel`), so only a command
that selects a model imports it.

The arithmetic is scipy's and the candidate's, operation for operation, but the elementary functions (exp,
log, expm1, sin) are the C library's here where numpy has its own vectorised ones, and short sums run in a
different order: iterates differ in the last bits, and a fit ends where scipy's does to about 1e-9 of
each parameter (``benchmarks/allan_model.py`` compares the chosen models with those scipy gave).

Why this module is long: it is one solver, scipy's ``trf_bounds`` and the helpers it calls, ported step
for step so that it can be read beside scipy's two files; split, the port would no longer follow them.
"""

from __future__ import annotations

import math

import numba
import numpy as np

NONE = -99  # no termination status yet (scipy's None)
FTOL = XTOL = GTOL = 1e-8  # least_squares' defaults
JAC_STEP = 1e-6  # in the log of a time constant or frequency: the Jacobian's central differences
TINY = np.finfo(np.float64).tiny
# division by zero gives inf or nan as in numpy (scipy's secular equation may divide by a zero column's
# singular value on its way to the same step), not Python's ZeroDivisionError
_jit = numba.njit(cache=True, error_model="numpy")


@_jit
def _norm(x: np.ndarray) -> float:
    return math.sqrt(np.dot(x, x))


@_jit
def _gm(tau: np.ndarray, t_c: float, out: np.ndarray) -> None:
    """gauss_markov_avar(tau, t_c) into ``out``."""
    for i in range(len(tau)):
        x = tau[i] / t_c
        if x < 1e-3:
            bracket = x**2 / 3.0 - x**3.0 / 4.0
        else:
            u = -math.expm1(-x)
            bracket = 1.0 - (2.0 * u + u * u) / (2.0 * x)
        out[i] = 2.0 * bracket / x


@_jit
def _filtered(tau: np.ndarray, t_f: float, dt: float, out: np.ndarray) -> None:
    """filtered_white_avar(tau, t_f, dt) into ``out``."""
    if dt <= 0.0 or dt / t_f < 1e-3:
        _gm(tau, t_f, out)
        for i in range(len(tau)):
            out[i] = out[i] / (2.0 * t_f)
        return
    p = math.exp(-dt / t_f)
    q = 1.0 - p
    s2 = q / (1.0 + p) / dt
    for i in range(len(tau)):
        m = tau[i] / dt
        pm = p**m
        out[i] = s2 / m**2 * (m + (2.0 * p * (m * q - 1.0 + pm) - p * (1.0 - pm) ** 2) / q**2)


@_jit
def _sin(tau: np.ndarray, f: float, out: np.ndarray) -> None:
    """sinusoid_avar(tau, f) into ``out``."""
    pf = math.pi * f
    for i in range(len(tau)):
        x = pf * tau[i]
        out[i] = math.sin(x) ** 4.0 / x**2


@_jit
def _column(k: int, value: float, tau: np.ndarray, n_terms: int, n_gm: int, filtered: bool, dt: float,
            a: np.ndarray) -> None:
    """Set the column of nonlinear parameter ``k`` (of x) to its shape at log value ``value``."""
    n_lin = a.shape[1]
    first_gm = n_lin + (1 if filtered else 0)
    if filtered and k == n_lin:
        _filtered(tau, math.exp(value), dt, a[:, 0])  # N is the combination's first term
    elif k < first_gm + n_gm:
        _gm(tau, math.exp(value), a[:, n_terms + k - first_gm])
    else:
        _sin(tau, math.exp(value), a[:, n_terms + k - first_gm])


@_jit
def _columns(x: np.ndarray, tau: np.ndarray, fixed: np.ndarray, n_terms: int, n_gm: int, filtered: bool,
             dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(columns, coefficients) at the log parameters ``x``."""
    n_lin = fixed.shape[1]
    c = np.exp(np.minimum(x[:n_lin], 300.0))
    a = fixed.copy()
    for k in range(n_lin, len(x)):
        _column(k, x[k], tau, n_terms, n_gm, filtered, dt, a)
    return a, c


@_jit
def _residuals(a: np.ndarray, c: np.ndarray, w: np.ndarray, log_avar: np.ndarray) -> np.ndarray:
    model = np.dot(np.ascontiguousarray(a), c)
    return w * (log_avar - np.log(np.maximum(model, TINY)))


@_jit
def _fun(x: np.ndarray, tau: np.ndarray, fixed: np.ndarray, n_terms: int, n_gm: int, filtered: bool,
         dt: float, w: np.ndarray, log_avar: np.ndarray) -> np.ndarray:
    a, c = _columns(x, tau, fixed, n_terms, n_gm, filtered, dt)
    return _residuals(a, c, w, log_avar)


@_jit
def _jac(x: np.ndarray, tau: np.ndarray, fixed: np.ndarray, n_terms: int, n_gm: int, filtered: bool,
         dt: float, w: np.ndarray, log_avar: np.ndarray) -> np.ndarray:
    """d r / d log c_j = -w c_j col_j / model, exactly; the time constants by central differences."""
    a, c = _columns(x, tau, fixed, n_terms, n_gm, filtered, dt)
    m, n_lin = a.shape
    jac = np.empty((m, len(x)))
    for i in range(m):
        s = 0.0
        for j in range(n_lin):
            s += a[i, j] * c[j]
        model = max(s, TINY)
        for j in range(n_lin):
            jac[i, j] = -w[i] * (a[i, j] * c[j]) / model
    moved = np.empty_like(a)
    for k in range(n_lin, len(x)):
        moved[:, :] = a
        _column(k, x[k] + JAC_STEP, tau, n_terms, n_gm, filtered, dt, moved)
        r_up = _residuals(moved, c, w, log_avar)
        moved[:, :] = a
        _column(k, x[k] - JAC_STEP, tau, n_terms, n_gm, filtered, dt, moved)
        r_down = _residuals(moved, c, w, log_avar)
        jac[:, k] = (r_up - r_down) / (2.0 * JAC_STEP)
    return jac


@_jit
def _cl_scaling(x: np.ndarray, g: np.ndarray, lb: np.ndarray, ub: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Coleman-Li scaling vector v and its derivative dv (common.CL_scaling_vector)."""
    v = np.ones_like(x)
    dv = np.zeros_like(x)
    for i in range(len(x)):
        if g[i] < 0 and np.isfinite(ub[i]):
            v[i] = ub[i] - x[i]
            dv[i] = -1.0
        if g[i] > 0 and np.isfinite(lb[i]):
            v[i] = x[i] - lb[i]
            dv[i] = 1.0
    return v, dv


@_jit
def _nextafter(a: float, b: float) -> float:
    if a == b or not np.isfinite(a):
        return b
    if a == 0.0:
        tiny_sub = np.array([1], dtype=np.int64).view(np.float64)[0]
        return tiny_sub if b > 0 else -tiny_sub
    bits = np.array([a]).view(np.int64)[0]
    bits = bits + 1 if (b > a) == (a > 0) else bits - 1
    return np.array([bits]).view(np.float64)[0]


@_jit
def _strictly_feasible(x: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """common.make_strictly_feasible(x, lb, ub, rstep=0)."""
    x_new = x.copy()
    for i in range(len(x)):
        active = 0
        if x[i] <= lb[i]:
            active = -1
        if x[i] >= ub[i]:
            active = 1
        if active == -1:
            x_new[i] = _nextafter(lb[i], ub[i])
        elif active == 1:
            x_new[i] = _nextafter(ub[i], lb[i])
        if x_new[i] < lb[i] or x_new[i] > ub[i]:
            x_new[i] = 0.5 * (lb[i] + ub[i])
    return x_new


@_jit
def _phi(alpha: float, suf: np.ndarray, s: np.ndarray, delta: float) -> tuple[float, float]:
    denom = s**2 + alpha
    p_norm = _norm(suf / denom)
    return p_norm - delta, -np.sum(suf**2 / denom**3.0) / p_norm


@_jit
def _solve_tr(n: int, m: int, uf: np.ndarray, s: np.ndarray, v: np.ndarray, delta: float,
              initial_alpha: float) -> tuple[np.ndarray, float]:
    """common.solve_lsq_trust_region (rtol 0.01, 10 iterations at most)."""
    suf = s * uf
    eps = np.finfo(np.float64).eps
    full_rank = False
    if m >= n:
        full_rank = s[-1] > eps * m * s[0]
    if full_rank:
        p = -np.dot(v, uf / s)
        if _norm(p) <= delta:
            return p, 0.0
    alpha_upper = _norm(suf) / delta
    alpha_lower = 0.0
    if full_rank:
        phi, phi_prime = _phi(0.0, suf, s, delta)
        alpha_lower = -phi / phi_prime
    if not full_rank and initial_alpha == 0:
        alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
    else:
        alpha = initial_alpha
    for _ in range(10):
        if alpha < alpha_lower or alpha > alpha_upper:
            alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
        phi, phi_prime = _phi(alpha, suf, s, delta)
        if phi < 0:
            alpha_upper = alpha
        ratio = phi / phi_prime
        alpha_lower = max(alpha_lower, alpha - ratio)
        alpha -= (phi + delta) * ratio / delta
        if abs(phi) < 0.01 * delta:
            break
    p = -np.dot(v, suf / (s**2 + alpha))
    p *= delta / _norm(p)
    return p, alpha


@_jit
def _to_bound(x: np.ndarray, s: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> tuple[float, np.ndarray]:
    """common.step_size_to_bound: the step along s to the first bound, and which bounds it hits."""
    steps = np.full(len(x), np.inf)
    for i in range(len(x)):
        if s[i] != 0:
            steps[i] = max((lb[i] - x[i]) / s[i], (ub[i] - x[i]) / s[i])
    min_step = np.min(steps)
    hits = np.zeros(len(x), dtype=np.int64)
    for i in range(len(x)):
        if steps[i] == min_step:
            hits[i] = 1 if s[i] > 0 else (-1 if s[i] < 0 else 0)
    return min_step, hits


@_jit
def _intersect(x: np.ndarray, s: np.ndarray, delta: float) -> tuple[float, float]:
    """common.intersect_trust_region."""
    a = np.dot(s, s)
    if a == 0:
        raise ValueError("`s` is zero.")
    b = np.dot(x, s)
    c = np.dot(x, x) - delta**2
    if c > 0:
        raise ValueError("`x` is not within the trust region.")
    d = math.sqrt(b * b - a * c)
    q = -(b + math.copysign(d, b))
    t1 = q / a
    t2 = c / q
    return (t1, t2) if t1 < t2 else (t2, t1)


@_jit
def _quadratic_1d(j_h: np.ndarray, g: np.ndarray, s: np.ndarray, diag: np.ndarray, s0: np.ndarray,
                  with_s0: bool) -> tuple[float, float, float]:
    """common.build_quadratic_1d with diag (and s0 where ``with_s0``)."""
    v = np.dot(j_h, s)
    a = np.dot(v, v)
    a += np.dot(s * diag, s)
    a *= 0.5
    b = np.dot(g, s)
    c = 0.0
    if with_s0:
        u = np.dot(j_h, s0)
        b += np.dot(u, v)
        c = 0.5 * np.dot(u, u) + np.dot(g, s0)
        b += np.dot(s0 * diag, s)
        c += 0.5 * np.dot(s0 * diag, s0)
    return a, b, c


@_jit
def _minimize_1d(a: float, b: float, lb: float, ub: float, c: float) -> tuple[float, float]:
    """common.minimize_quadratic_1d: the first smallest of the ends and the interior extremum."""
    best_t, best_y = lb, lb * (a * lb + b) + c
    y = ub * (a * ub + b) + c
    if y < best_y:
        best_t, best_y = ub, y
    if a != 0:
        extremum = -0.5 * b / a
        if lb < extremum < ub:
            y = extremum * (a * extremum + b) + c
            if y < best_y:
                best_t, best_y = extremum, y
    return best_t, best_y


@_jit
def _evaluate(j_h: np.ndarray, g: np.ndarray, s: np.ndarray, diag: np.ndarray) -> float:
    js = np.dot(j_h, s)
    q = np.dot(js, js)
    q += np.dot(s * diag, s)
    return 0.5 * q + np.dot(s, g)


@_jit
def _select_step(x: np.ndarray, j_h: np.ndarray, diag_h: np.ndarray, g_h: np.ndarray, p: np.ndarray,
                 p_h: np.ndarray, d: np.ndarray, delta: float, lb: np.ndarray, ub: np.ndarray, theta: float
                 ) -> tuple[np.ndarray, np.ndarray, float]:
    """trf.select_step: the trust-region step, its reflection at the first bound, or the gradient's."""
    xp = x + p
    if np.all((xp >= lb) & (xp <= ub)):
        return p, p_h, -_evaluate(j_h, g_h, p_h, diag_h)
    p_stride, hits = _to_bound(x, p, lb, ub)
    r_h = p_h.copy()
    for i in range(len(r_h)):
        if hits[i] != 0:
            r_h[i] *= -1
    r = d * r_h
    p = p * p_stride
    p_h = p_h * p_stride
    x_on_bound = x + p
    _, to_tr = _intersect(p_h, r_h, delta)
    to_bound, _ = _to_bound(x_on_bound, r, lb, ub)
    r_stride = min(to_bound, to_tr)
    if r_stride > 0:
        r_stride_l = (1 - theta) * p_stride / r_stride
        r_stride_u = theta * to_bound if r_stride == to_bound else to_tr
    else:
        r_stride_l = 0.0
        r_stride_u = -1.0
    if r_stride_l <= r_stride_u:
        a, b, c = _quadratic_1d(j_h, g_h, r_h, diag_h, p_h, True)
        r_stride, r_value = _minimize_1d(a, b, r_stride_l, r_stride_u, c)
        r_h = r_h * r_stride
        r_h += p_h
        r = r_h * d
    else:
        r_value = np.inf
    p = p * theta
    p_h = p_h * theta
    p_value = _evaluate(j_h, g_h, p_h, diag_h)
    ag_h = -g_h
    ag = d * ag_h
    to_tr = delta / _norm(ag_h)
    to_bound, _ = _to_bound(x, ag, lb, ub)
    ag_stride = theta * to_bound if to_bound < to_tr else to_tr
    a, b, _ = _quadratic_1d(j_h, g_h, ag_h, diag_h, ag_h, False)
    ag_stride, ag_value = _minimize_1d(a, b, 0.0, ag_stride, 0.0)
    ag_h = ag_h * ag_stride
    ag = ag * ag_stride
    if p_value < r_value and p_value < ag_value:
        return p, p_h, -p_value
    if r_value < p_value and r_value < ag_value:
        return r, r_h, -r_value
    return ag, ag_h, -ag_value


@_jit
def solve(x0: np.ndarray, lb: np.ndarray, ub: np.ndarray, tau: np.ndarray, fixed: np.ndarray, n_terms: int,
          n_gm: int, filtered: bool, dt: float, w: np.ndarray, log_avar: np.ndarray, max_nfev: int
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Minimise the candidate's (1) from ``x0`` (strictly inside the bounds) within ``lb``, ``ub``.

    Parameters
    ----------
    x0, lb, ub : ndarray, (P,)
        Start and bounds of the log parameters (coefficients, then T_f, T_k, f_j).
    tau : ndarray, (M,)
        Cluster times.
    fixed : ndarray, (M, C)
        The coefficients' columns that no time constant moves (the others are overwritten).
    n_terms, n_gm : int
        IEEE terms (N first) and Gauss-Markov processes of the combination.
    filtered : bool
        Whether N is seen through the filter (then x[C] is log T_f).
    dt : float
        Sample period.
    w, log_avar : ndarray, (M,)
        The residuals' weights and the measured log variances less the log-chi-square mean.
    max_nfev : int
        Most evaluations of the residuals.

    Returns
    -------
    tuple
        (x, residuals at x, Jacobian at x, termination status as scipy's: 0 evaluations exhausted, 1 gtol,
        2 ftol, 3 xtol, 4 ftol and xtol).
    """
    x = x0.copy()
    f = _fun(x, tau, fixed, n_terms, n_gm, filtered, dt, w, log_avar)
    nfev = 1
    jac = _jac(x, tau, fixed, n_terms, n_gm, filtered, dt, w, log_avar)
    m, n = jac.shape
    cost = 0.5 * np.dot(f, f)
    g = np.dot(jac.T, f)
    v, dv = _cl_scaling(x, g, lb, ub)
    delta = _norm(x0 / np.sqrt(v))
    if delta == 0:
        delta = 1.0
    f_aug = np.zeros(m + n)
    j_aug = np.zeros((m + n, n))
    alpha = 0.0
    status = NONE
    x_new = x
    f_new = f
    cost_new = cost
    while True:
        v, dv = _cl_scaling(x, g, lb, ub)
        g_norm = np.max(np.abs(g * v))
        if g_norm < GTOL:
            status = 1
        if status != NONE or nfev == max_nfev:
            break
        d = np.sqrt(v)
        diag_h = g * dv
        g_h = d * g
        f_aug[:m] = f
        j_aug[:m] = jac * d
        j_aug[m:] = 0.0
        for i in range(n):
            j_aug[m + i, i] = math.sqrt(diag_h[i])
        j_h = np.ascontiguousarray(j_aug[:m])
        u_mat, s, vt = np.linalg.svd(j_aug, full_matrices=False)
        v_mat = np.ascontiguousarray(vt.T)
        uf = np.dot(u_mat.T, f_aug)
        theta = max(0.995, 1 - g_norm)
        actual_reduction = -1.0
        while actual_reduction <= 0 and nfev < max_nfev:
            p_h, alpha = _solve_tr(n, m, uf, s, v_mat, delta, alpha)
            p = d * p_h
            step, step_h, predicted = _select_step(x, j_h, diag_h, g_h, p, p_h, d, delta, lb, ub, theta)
            x_new = _strictly_feasible(x + step, lb, ub)
            f_new = _fun(x_new, tau, fixed, n_terms, n_gm, filtered, dt, w, log_avar)
            nfev += 1
            step_h_norm = _norm(step_h)
            if not np.all(np.isfinite(f_new)):
                delta = 0.25 * step_h_norm
                continue
            cost_new = 0.5 * np.dot(f_new, f_new)
            actual_reduction = cost - cost_new
            # trf.update_tr_radius
            if predicted > 0:
                ratio = actual_reduction / predicted
            elif predicted == actual_reduction == 0:
                ratio = 1.0
            else:
                ratio = 0.0
            delta_new = delta
            if ratio < 0.25:
                delta_new = 0.25 * step_h_norm
            elif ratio > 0.75 and step_h_norm > 0.95 * delta:
                delta_new = delta * 2.0
            # common.check_termination
            ftol_ok = actual_reduction < FTOL * cost and ratio > 0.25
            xtol_ok = _norm(step) < XTOL * (XTOL + _norm(x))
            if ftol_ok and xtol_ok:
                status = 4
            elif ftol_ok:
                status = 2
            elif xtol_ok:
                status = 3
            if status != NONE:
                break
            alpha *= delta / delta_new
            delta = delta_new
        if actual_reduction > 0:
            x = x_new
            f = f_new
            cost = cost_new
            jac = _jac(x, tau, fixed, n_terms, n_gm, filtered, dt, w, log_avar)
            g = np.dot(jac.T, f)
    if status == NONE:
        status = 0
    return x, f, jac, status


def cached() -> bool:
    """Whether numba's cache holds :func:`solve` (its index file beside this module or in
    ``NUMBA_CACHE_DIR``): a process that finds it loads the machine code instead of compiling."""
    import os

    cache = getattr(solve, "_cache", None)
    index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
    return index is not None and os.path.exists(index)


def compile_now() -> None:
    """Compile :func:`solve` (and everything it calls) for the one signature the model selection uses, by
    solving a two-parameter problem; numba caches the result on disk."""
    tau = np.geomspace(0.01, 100.0, 12)
    fixed = np.ascontiguousarray(np.stack([1.0 / tau, tau], axis=1))
    log_avar = np.log(2e-6 / tau + 1e-9 * tau)
    solve(np.zeros(2), np.full(2, -np.inf), np.full(2, np.inf), tau, fixed, 2, 0, False, 0.01,
          np.ones(len(tau)), log_avar, 100)
