"""The Earth's magnetic field at a place and date, from the World Magnetic Model (WMM, NOAA/NCEI and
the British Geological Survey) as the pygeomag package evaluates it.

``imu-station calibrate --method mag`` scales the corrected field to the model's magnitude and
compares its estimated dip with the model's. The WMM is a degree-12 spherical-harmonic model
renewed every five years; pygeomag ships the coefficients (WMM2025 is valid 2025.0 to 2030.0) and
picks the epoch from the date. Its stated accuracy is about 0.15 uT in magnitude and 0.2 deg in
dip (1 sigma, the WMM technical report); local anomalies (geology, buildings) are larger.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass

from station.errors import StationError

# The model's heights: from below sea level to the top of the model's validity (WMM: -1 to 850 km).
MIN_HEIGHT_M, MAX_HEIGHT_M = -1000.0, 850_000.0


@dataclass(frozen=True)
class GeomagneticField:
    """The field at a place and date: magnitude (uT), dip (deg, positive down), declination (deg,
    east of true north) and the model that gave them."""

    magnitude_ut: float
    dip_deg: float
    declination_deg: float
    model: str

    def describe(self) -> str:
        """``47.63 uT, dip 61.24 deg, declination 3.38 deg (WMM 2025, 2026-11-26)``."""
        return (f"{self.magnitude_ut:.2f} uT, dip {self.dip_deg:.2f} deg, declination "
                f"{self.declination_deg:.2f} deg ({self.model})")


def decimal_year(date: _dt.date) -> float:
    """The date as a decimal year (2026-07-02 is about 2026.5), as the model takes it.

    Parameters
    ----------
    date : datetime.date

    Returns
    -------
    float
    """
    start = _dt.date(date.year, 1, 1)
    days = (_dt.date(date.year + 1, 1, 1) - start).days
    return date.year + (date - start).days / days


def field_at(latitude_deg: float, longitude_deg: float, height_m: float, date: _dt.date) -> GeomagneticField:
    """The WMM's field at a geodetic place (WGS-84) and date.

    Parameters
    ----------
    latitude_deg, longitude_deg : float
        Geodetic latitude (-90..90) and longitude (-180..360), degrees.
    height_m : float
        Height above the WGS-84 ellipsoid, m.
    date : datetime.date

    Returns
    -------
    GeomagneticField

    Raises
    ------
    StationError
        A place out of range, or a date outside every model pygeomag carries (naming the span).
    """
    from pygeomag import GeoMag

    if not -90.0 <= latitude_deg <= 90.0 or not -180.0 <= longitude_deg <= 360.0:
        raise StationError(f"latitude {latitude_deg:g} / longitude {longitude_deg:g} deg is not a place on "
                           "Earth: latitude -90..90, longitude -180..360 degrees")
    if not MIN_HEIGHT_M <= height_m <= MAX_HEIGHT_M:
        raise StationError(f"height {height_m:g} m is outside the geomagnetic model's "
                           f"{MIN_HEIGHT_M:g}..{MAX_HEIGHT_M:g} m")
    year = decimal_year(date)
    try:
        model = GeoMag(base_year=_dt.datetime(date.year, date.month, date.day))
        result = model.calculate(glat=latitude_deg, glon=longitude_deg, alt=height_m / 1000.0, time=year)
    except ValueError as exc:
        raise StationError(f"the World Magnetic Model has no field for {date.isoformat()} ({exc}); give a "
                           "date within a model's five-year span (WMM2025: 2025 to 2029), or the field's "
                           "magnitude with --field UT") from None
    # the WMM's epochs are the years divisible by five; pygeomag picks the one the date falls in
    epoch = date.year - date.year % 5
    return GeomagneticField(magnitude_ut=float(result.f) / 1000.0, dip_deg=float(result.i),
                            declination_deg=float(result.d), model=f"WMM {epoch}, {date.isoformat()}")
