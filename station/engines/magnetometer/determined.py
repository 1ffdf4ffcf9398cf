"""Whether a magnetometer capture can determine a calibration: did the field's direction move
beyond the noise, does the sphere through the readings locate the hard iron, and is every fitted
value real, finite and known to better than its own size.

A still unit's readings are a cloud of noise around one point. A sphere fitted through that cloud
(eq. (7) of :mod:`~station.engines.magnetometer.fit`) has its centre inside it and a radius of
about sqrt(3) sigma, so the directions "seen from the centre" point everywhere and count as a full
coverage of the sphere. Directions only mean something once the field moved by much more than the
noise, and the centre is only where the sphere puts it when the readings bend enough to fix it.

The noise sigma of the readings (per axis, microtesla) is taken from their second differences
within windows of ``NOISE_WINDOW`` readings (held repeats dropped first): for white noise
d2_i = m_{i+1} - 2 m_i + m_{i-1} has a variance of 6 sigma^2 while a smooth turn adds only its
acceleration times dt^2, so

    sigma_w = 1.4826 median|d2 - median d2| / sqrt(6)     (each window w, the axes pooled)     (1)
    sigma   = max(percentile_20(sigma_w), q / sqrt(12))

the low percentile picking the windows where the unit paused (a unit never still gives an upper
bound, which only makes the checks below stricter) and q, the smallest step between two readings,
the quantisation floor. The sphere's centre c and radius r (``fit`` eq. (7)) are trusted when

    r >= K sigma                                 (a direction's noise sigma / r under 1/K rad)   (2)
    sqrt(max eig cov(c)) <= f r                  (the centre known to f r, 1 sigma)               (3)

with cov(c) the linear least squares' s^2 (D^T D)^-1 of eq. (7) (D its design, s^2 its residual
variance); K = ``MIN_RADIUS_NOISE``, f = ``MAX_CENTRE_SHARE``. A noise cloud fails (2) (r about 1.7
sigma); an arc or a small patch of the sphere fails (3) (its curvature hides in the noise).

A finished fit is written only when every value and 1-sigma is a finite real number and each
1-sigma is under ``MAX_SIGMA_SHARE`` of the size of what it belongs to:

    sd(A_jk) <= s ||A||_2,  sd(C_jk) <= s ||C||_2,  sd(b_j) <= s F,  sd(F) <= s F,
    sd(angles) <= s rad                                                                          (4)

(s = ``MAX_SIGMA_SHARE``). An entry's own value is no yardstick: the off-diagonal entries and the
hard iron of a good unit are near zero and a permuted mounting has a zero diagonal, but a 1-sigma
that is a tenth of the whole matrix means the capture did not determine it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from station.engines.magnetometer.fit import Start, sphere_fit
from station.errors import EngineInputError

# Readings per window of eq. (1), and the percentile of the windows' sigma taken.
NOISE_WINDOW, NOISE_PERCENTILE = 50, 20.0
# Eq. (2): the sphere's radius over the noise. A still unit's cloud gives about 1.7; a real field
# (25-65 uT) over a magnetometer's noise (0.1-1 uT) 50 or more; 10 keeps a direction within 6 deg.
MIN_RADIUS_NOISE = 10.0
# Eq. (3): the centre's 1-sigma over the radius (0.05: a direction off by 3 deg at most).
MAX_CENTRE_SHARE = 0.05
# Eq. (4): a 1-sigma over this share of its quantity's size is not a calibration.
MAX_SIGMA_SHARE = 0.1

_TURN = ("capture again turning the unit slowly through many orientations (tilt it, roll it and turn it "
         "around), pausing now and then")


def reading_noise(m: np.ndarray) -> float:
    """Eq. (1): the readings' noise per axis, microtesla.

    Parameters
    ----------
    m : ndarray, (n, 3)
        Readings in time order (finite rows).

    Returns
    -------
    float
        sigma; 0.0 with fewer than three distinct readings.
    """
    m = np.asarray(m, float).reshape(-1, 3)
    if len(m) > 1:  # a magnetometer slower than its stream repeats its last reading: one sample, not two
        m = m[np.concatenate([[True], np.any(m[1:] != m[:-1], axis=1)])]
    if len(m) < 3:
        return 0.0
    d2 = m[2:] - 2.0 * m[1:-1] + m[:-2]
    sigmas = []
    for start in range(0, len(d2), NOISE_WINDOW):
        w = d2[start:start + NOISE_WINDOW]
        if len(w) < 5:
            continue
        sigmas.append(1.4826 * float(np.median(np.abs(w - np.median(w, axis=0)))) / np.sqrt(6.0))
    sigma = float(np.percentile(sigmas, NOISE_PERCENTILE)) if sigmas else 0.0
    steps = np.abs(np.diff(np.sort(m, axis=0), axis=0))
    steps = steps[steps > 0]
    floor = float(steps.min()) / np.sqrt(12.0) if len(steps) else 0.0
    return max(sigma, floor)


@dataclass(frozen=True)
class Centre:
    """The sphere through the readings and whether it locates the hard iron (eqs. (2)-(3)).

    Attributes
    ----------
    start : Start
        The least-squares sphere (``fit`` eq. (7)).
    radius : float
        Its radius, microtesla.
    centre_sd : float
        The centre's 1-sigma (largest axis), microtesla.
    noise : float
        The readings' noise, eq. (1).
    problem : str or None
        Why the centre is not determined, with what to do; None when it is.
    """

    start: Start
    radius: float
    centre_sd: float
    noise: float
    problem: str | None

    @property
    def determined(self) -> bool:
        """Eqs. (2) and (3) hold."""
        return self.problem is None


def sphere_centre(m: np.ndarray, noise: float | None = None) -> Centre:
    """The sphere through ``m`` and whether it is determined (eqs. (2)-(3)).

    Parameters
    ----------
    m : ndarray, (n, 3)
        Raw readings (finite rows), in time order when ``noise`` is not given.
    noise : float, optional
        The readings' noise (microtesla); default :func:`reading_noise` of ``m``.

    Returns
    -------
    Centre
    """
    m = np.asarray(m, float).reshape(-1, 3)
    sigma = reading_noise(m) if noise is None else float(noise)
    if len(m) < 5:
        return Centre(Start(np.zeros(3), np.eye(3), "sphere"), 0.0, np.inf, sigma,
                      f"{len(m)} readings cannot place a sphere; {_TURN}")
    start = sphere_fit(m)
    radius = 1.0 / float(start.correction[0, 0])
    centred = m - m.mean(axis=0)
    design = np.column_stack([2.0 * centred, np.ones(len(m))])
    target = np.sum(centred * centred, axis=1)
    sol, *_ = np.linalg.lstsq(design, target, rcond=None)
    dof = max(len(m) - 4, 1)
    s2 = float(np.sum((target - design @ sol) ** 2)) / dof
    try:
        cov = s2 * np.linalg.inv(design.T @ design)[:3, :3]
        centre_sd = float(np.sqrt(max(np.linalg.eigvalsh(0.5 * (cov + cov.T)).max(), 0.0)))
    except np.linalg.LinAlgError:
        centre_sd = np.inf
    problem = None
    spread = float(np.max(np.ptp(m, axis=0)))
    if not np.isfinite(radius) or radius < MIN_RADIUS_NOISE * sigma:
        problem = (f"the field's direction did not move beyond the noise: the readings spread over "
                   f"{spread:.3g} uT against a noise of {sigma:.2g} uT (the unit was still, or its "
                   f"magnetometer sees no field); {_TURN}")
    elif not np.isfinite(centre_sd) or centre_sd > MAX_CENTRE_SHARE * radius:
        problem = (f"the readings do not locate the hard iron (the sphere through them, radius {radius:.3g} "
                   f"uT, has its centre only to +/- {centre_sd:.2g} uT): the unit turned through too small "
                   f"an angle; {_TURN}")
    return Centre(start, radius, centre_sd, sigma, problem)


def check_centre(m: np.ndarray) -> Centre:
    """:func:`sphere_centre`, refusing a capture whose centre is not determined.

    Parameters
    ----------
    m : ndarray, (n, 3)
        Raw readings in time order.

    Returns
    -------
    Centre
        A determined one.

    Raises
    ------
    EngineInputError
        Eq. (2) or (3) fails; the message says what to do.
    """
    centre = sphere_centre(m)
    if centre.problem is not None:
        raise EngineInputError(centre.problem)
    return centre


def _worst(sd: np.ndarray, size: float) -> float:
    """The largest 1-sigma over the yardstick (inf where either is not a finite real number)."""
    sd = np.asarray(sd)
    if np.iscomplexobj(sd) or not np.all(np.isfinite(sd)) or not np.isfinite(size) or size <= 0:
        return np.inf
    return float(np.max(np.abs(sd))) / size if sd.size else 0.0


def check_result(matrix: np.ndarray, correction: np.ndarray, bias: np.ndarray, field_norm: float,
                 stddev: dict[str, np.ndarray | float], angles: dict[str, float | None]) -> None:
    """Eq. (4): refuse a fit with a value or 1-sigma that is not a finite real number, or a 1-sigma
    above ``MAX_SIGMA_SHARE`` of its quantity's size.

    Parameters
    ----------
    matrix, correction : ndarray, (3, 3)
        A and C.
    bias : ndarray, (3,)
        b, microtesla.
    field_norm : float
        F, microtesla.
    stddev : dict
        The fit's 1-sigma (``MagCalibration.stddev``: ``matrix``, ``correction``, ``bias`` and,
        where estimated, ``field_norm``, ``alignment_deg``, ``dip_deg``).
    angles : dict
        Reported angles (deg) by name (``dip_deg``, ``alignment_deg``), None where not fitted.

    Raises
    ------
    EngineInputError
        Naming the worst quantity and what to do.
    """
    values = [np.asarray(matrix), np.asarray(correction), np.asarray(bias), np.asarray(field_norm)]
    values += [np.asarray(v) for v in angles.values() if v is not None]
    if any(np.iscomplexobj(v) or not np.all(np.isfinite(v)) for v in values):
        raise EngineInputError(f"the fit did not converge to a real, finite calibration; {_TURN}")
    f = float(field_norm)
    scale_a = float(np.linalg.norm(matrix, 2))
    scale_c = float(np.linalg.norm(correction, 2))
    ratios = {"the matrix A": _worst(np.asarray(stddev["matrix"]), scale_a),
              "the correction C": _worst(np.asarray(stddev["correction"]), scale_c),
              "the hard iron": _worst(np.asarray(stddev["bias"]), f)}
    if "field_norm" in stddev:
        ratios["the field magnitude"] = _worst(np.asarray(stddev["field_norm"]), f)
    for name in ("alignment_deg", "dip_deg"):
        if name in stddev:
            ratios[name.replace("_deg", "")] = _worst(np.radians(np.asarray(stddev[name], float)), 1.0)
    name, worst = max(ratios.items(), key=lambda kv: kv[1])
    if worst > MAX_SIGMA_SHARE:
        size = "is not a finite number" if not np.isfinite(worst) else f"is {worst:.2g} of its size"
        raise EngineInputError(
            f"the capture does not determine the magnetometer's calibration: the 1-sigma of {name} {size} "
            f"(at most {MAX_SIGMA_SHARE:g} is written); {_TURN}")
