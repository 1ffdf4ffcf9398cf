"""Gauss-Markov process noise for EKF-style estimators (``imu-station allan --gm FILE.yaml``).

Per sensor and axis, the white noise N, the random walk K and every first-order Gauss-Markov process
[sigma, tau_c] of the ``noise`` section, each in continuous time and discretised for a filter step
dt = 1 / rate (van Loan's exact discretisation of the scalar systems; e.g. Maybeck, "Stochastic Models,
Estimation and Control", vol. 1, sec. 4.9):

    white noise      measurement variance        r_d = N^2 / dt
    random walk      b_{k+1} = b_k + w_k,        q_d = K^2 dt
    Gauss-Markov     x_{k+1} = phi x_k + w_k,    phi = exp(-dt / tau_c),  q_d = sigma^2 (1 - phi^2)
                     (continuous: dx/dt = -x / tau_c + w, spectral density q_c = 2 sigma^2 / tau_c)

The state variance of the discretised process stays sigma^2: q_d / (1 - phi^2) = sigma^2, whatever dt.
"""

from __future__ import annotations

import math
from typing import Any

import yaml

from station.errors import EngineInputError
from station.export.params.file import gauss_markov_of

SCHEMA = "imu-station/gm/1"
SENSORS = {"gyro": ("gx", "gy", "gz"), "accel": ("ax", "ay", "az")}


def discrete_gm(sigma: float, tau_c: float, dt: float) -> dict[str, float]:
    """The discrete-time form of one Gauss-Markov process for a step ``dt``.

    Parameters
    ----------
    sigma : float
        Steady-state 1-sigma, in the sensor's unit.
    tau_c : float
        Correlation time, s.
    dt : float
        Filter step, s.

    Returns
    -------
    dict
        ``phi``, ``q_d`` (variance of the discrete driving noise) and ``q_c`` (continuous spectral density).
    """
    phi = math.exp(-dt / tau_c)
    return {"phi": phi, "q_d": sigma**2 * -math.expm1(-2.0 * dt / tau_c), "q_c": 2.0 * sigma**2 / tau_c}


def gm_yaml(noise: dict[str, Any], rate_hz: float | None = None) -> str:
    """The ``--gm`` file: every axis's N, K and Gauss-Markov processes, continuous and discrete.

    Parameters
    ----------
    noise : dict
        The ``noise`` section (as written to the parameter file; the old ``gauss_markov`` key is read too).
    rate_hz : float, optional
        The filter's rate; default the record's.

    Returns
    -------
    str
        YAML text.

    Raises
    ------
    EngineInputError
        A rate that is not positive.
    """
    rate = float(rate_hz if rate_hz is not None else noise["record"]["rate_hz"])
    if not rate > 0:
        raise EngineInputError(f"--gm-rate {rate:g}: give the filter's rate in Hz, above 0")
    dt = 1.0 / rate
    doc: dict[str, Any] = {"schema": SCHEMA, "rate_hz": rate, "dt_s": dt,
                           "model": "x_{k+1} = phi x_k + w_k, var(w_k) = q_d; phi = exp(-dt/tau_c), q_d = "
                                    "sigma^2 (1 - phi^2); white noise r_d = N^2/dt; random walk q_d = K^2 dt"}
    for sensor, axes in SENSORS.items():
        section = noise.get(sensor)
        if not section:
            continue
        processes = gauss_markov_of(section) or [[] for _ in axes]
        units = (noise.get("units") or {}).get(sensor, {})
        per_axis = {}
        for j, axis in enumerate(axes):
            n = (section.get("N") or [None] * 3)[j]
            k = (section.get("K") or [None] * 3)[j]
            entry: dict[str, Any] = {
                "N": n, "K": k,
                "white_noise_variance_r_d": None if n is None else n**2 / dt,
                "random_walk_q_d": None if k is None else k**2 * dt,
                "GM": [{"sigma": sigma, "tau_c": tau_c, **discrete_gm(sigma, tau_c, dt)}
                       for sigma, tau_c in (processes[j] or [])],
            }
            per_axis[axis] = entry
        doc[sensor] = {"units": {"N": units.get("N"), "K": units.get("K"), "sigma": units.get("B"),
                                 "tau_c": "s"}, **per_axis}
    header = (f"# Gauss-Markov process noise for an EKF at {rate:g} Hz, from imu-station allan.\n"
              "# Continuous: dx/dt = -x/tau_c + w, q_c = 2 sigma^2/tau_c; discrete: see 'model'.\n"
              "# The measured model: --inflate, which scales the estimators' files, does not apply here.\n")
    return header + yaml.safe_dump(doc, sort_keys=False)
