"""The inflation policy for noise values written for an estimator: one explicit factor, never a silent one.

A still record on a bench measures the sensor alone, at one temperature, not moving. In flight the
estimator also meets vibration (and its aliasing), temperature change, scale-factor and misalignment errors
on real motion, and timing jitter, none of which such a record shows, so its values make a filter trust the
IMU too much. Users multiply them; the sources say by how much:

- Kalibr's wiki, "IMU Noise Model", section "Kalibr IMU Noise Parameters in Practice": the model from a
  sensor "which does not undergo motion, and at constant temperature" is optimistic; "for lowest-cost
  sensors, increasing the noise model parameters by a factor of 10x or more may be necessary".
- OpenVINS' documentation, "Sensor Calibration", IMU Intrinsic Calibration (``docs/gs-calibration.dox``):
  "one may need to inflate the calculated values by 10-20 times to get usable sensor values".

The policy: ``--inflate K``, one factor K >= 1 (default 1: the values as measured) multiplying every value
written (each a density or a standard deviation, so the variances grow by K^2), stated in the file's header
and printed every time a file is written. One factor rather than one per term, as both sources give one:
different factors per term are filter tuning against flight logs (innovation test ratios), which a bench
record cannot measure.
"""

from __future__ import annotations

import math

from station.errors import EngineInputError

DEFAULT_FACTOR = 1.0
MAX_FACTOR = 1000.0
"""Far above any factor the sources name (10 to 20): a larger one is a typing error."""
SOURCES = ("Kalibr's wiki (IMU Noise Model): 10x or more for low-cost MEMS",
           "OpenVINS' docs (Sensor Calibration): 10-20x")


def check_factor(factor: float) -> float:
    """The inflation factor, refused unless 1 <= factor <= :data:`MAX_FACTOR`.

    Parameters
    ----------
    factor : float
        The factor asked for (``--inflate``).

    Returns
    -------
    float
        ``factor``.

    Raises
    ------
    EngineInputError
        A factor below 1 (it would make the filter trust the IMU more than a still bench does), above
        :data:`MAX_FACTOR`, or not a number.
    """
    if not (math.isfinite(factor) and 1.0 <= factor <= MAX_FACTOR):
        raise EngineInputError(f"--inflate {factor:g}: give a factor from 1 (the values as measured) to "
                               f"{MAX_FACTOR:g}; below 1 a filter would trust the IMU more than a still "
                               "bench record does")
    return float(factor)


def reason(factor: float) -> str:
    """The line printed whenever noise values are written for an estimator: the factor and why.

    Parameters
    ----------
    factor : float
        The inflation factor applied.

    Returns
    -------
    str
        One line naming the factor, what a still bench record misses, and the sources' factors.
    """
    why = ("a still bench record underestimates what vibration, temperature change and misalignment add "
           f"in flight ({'; '.join(SOURCES)})")
    if factor == 1.0:
        return (f"noise values as measured, not inflated (--inflate 1): {why}; choose a factor with "
                "--inflate K")
    return (f"noise values inflated by a factor of {factor:g} (--inflate {factor:g}, variances "
            f"x{factor**2:g}): {why}")


def header_lines(factor: float) -> list[str]:
    """The comment lines (without the comment mark) a written file carries about its inflation.

    Parameters
    ----------
    factor : float
        The inflation factor applied.

    Returns
    -------
    list of str
        Two lines: the factor applied to every value, and why (:func:`reason`'s sources).
    """
    what = ("values as measured on a still bench, not inflated (--inflate 1)" if factor == 1.0 else
            f"every value is the still bench value x {factor:g} (--inflate {factor:g})")
    return [f"{what}.", "A still bench record underestimates vibration, temperature change and misalignment "
            f"in flight: {'; '.join(SOURCES)}."]
