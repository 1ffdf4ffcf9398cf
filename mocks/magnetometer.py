"""The simulated unit's magnetometer and the local Earth field it measures.

The local field is set by its magnitude F (uT), dip (inclination) I and declination D. In
East-North-Up it is ``F (cos I sin D, cos I cos D, -sin I)``: horizontal towards magnetic north,
pointing down by the dip (positive in the northern hemisphere). The rig's world frame has z up
and x at azimuth ``heading`` (clockwise from true north), so with ``a = D - h``::

    m_world = F (cos I cos a, -cos I sin a, -sin I)                           (1)

The magnetometer sees the field in body axes ``b = R^T m_world`` (R the attitude, body to world;
body axes are the accelerometer's when its own misalignment is zero) and reports::

    raw = W C b + h + n,      raw = quantize(clip(raw, -saturation, +saturation))     (2)

with h the hard iron (uT), W the soft iron (symmetric positive definite), C a small rotation from
the body (accelerometer) axes to the magnetometer's axes and n white noise of ``noise_ut`` per
axis and sample. The correction that undoes eq. (2) is ``b = C^T W^-1 (raw - h)``
(:meth:`MagTruth.correct`): what a calibration of the magnetometer in accelerometer axes
(``frame: accel``) has to find.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocks.attitude import axis_angle_matrix

# The options of sim:// and imu-station simulate that give the unit a magnetometer (mag=1) and set
# the field it sits in.
MAG_OPTIONS = ("mag", "field", "dip", "declination")


@dataclass
class EarthField:
    """The local geomagnetic field: magnitude (uT), dip and declination (degrees), eq. (1)."""

    magnitude_ut: float = 50.0
    dip_deg: float = 60.0
    declination_deg: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 < self.magnitude_ut < 1000.0:
            raise ValueError(f"field magnitude {self.magnitude_ut} uT is outside 0..1000 uT")
        if not -90.0 <= self.dip_deg <= 90.0:
            raise ValueError(f"dip {self.dip_deg} deg is outside -90..90 deg")

    def world(self, heading_deg: float = 0.0) -> np.ndarray:
        """The field (uT) in the rig's world frame (z up, x at azimuth ``heading_deg``), eq. (1).

        Parameters
        ----------
        heading_deg : float
            Azimuth of world x, degrees clockwise from true north.

        Returns
        -------
        ndarray, (3,)
        """
        dip = np.radians(self.dip_deg)
        a = np.radians(self.declination_deg - heading_deg)
        return self.magnitude_ut * np.array([np.cos(dip) * np.cos(a), -np.cos(dip) * np.sin(a), -np.sin(dip)])


@dataclass
class MagTruth:
    """The magnetometer of eq. (2) and the field it sits in.

    Parameters
    ----------
    hard_iron : (3,) uT.
    soft_iron : (3, 3) symmetric positive definite W.
    rotation : (3, 3) C, body (accelerometer) axes to magnetometer axes.
    noise_ut : white noise per axis and sample, uT (scalar or (3,)).
    resolution : quantization step, uT (None: none).
    saturation : range, uT.
    field : the local Earth field.
    """

    hard_iron: np.ndarray = field(default_factory=lambda: np.zeros(3))
    soft_iron: np.ndarray = field(default_factory=lambda: np.eye(3))
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    noise_ut: np.ndarray = field(default_factory=lambda: np.zeros(3))
    resolution: float | None = None
    saturation: float = np.inf
    field: EarthField = field(default_factory=EarthField)

    def __post_init__(self) -> None:
        self.hard_iron = np.broadcast_to(np.asarray(self.hard_iron, float), (3,)).copy()
        self.noise_ut = np.broadcast_to(np.asarray(self.noise_ut, float), (3,)).copy()
        self.soft_iron = np.asarray(self.soft_iron, float).reshape(3, 3).copy()
        self.rotation = np.asarray(self.rotation, float).reshape(3, 3).copy()
        if not np.allclose(self.soft_iron, self.soft_iron.T) or np.linalg.eigvalsh(self.soft_iron).min() <= 0:
            raise ValueError("soft iron must be symmetric positive definite")
        r = self.rotation
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) <= 0:
            raise ValueError("rotation must be a proper rotation matrix")

    @classmethod
    def random(cls, seed: int, earth: EarthField | None = None) -> MagTruth:
        """A consumer magnetometer inside a small board: hard iron ~15 uT per axis, soft iron
        within a few per cent of identity (symmetric), 1-2 deg of rotation against the
        accelerometer, 0.15 uT noise, 0.1 uT resolution, +-1200 uT range.

        Parameters
        ----------
        seed : int
        earth : EarthField, optional
            The local field (default 50 uT, dip 60 deg).

        Returns
        -------
        MagTruth
        """
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x3A6]))
        a = rng.normal(0.0, 0.02, (3, 3))
        soft = np.eye(3) + np.diag(rng.normal(0.0, 0.04, 3)) + 0.5 * (a + a.T)
        axis = rng.standard_normal(3)
        angle = np.radians(rng.uniform(1.0, 2.0))
        return cls(hard_iron=rng.normal(0.0, 15.0, 3), soft_iron=soft,
                   rotation=axis_angle_matrix(axis / np.linalg.norm(axis), np.array([angle]))[0],
                   noise_ut=0.15, resolution=0.1, saturation=1200.0, field=earth or EarthField())

    def measure(self, field_body: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """raw of eq. (2) for the field in body axes (N, 3), uT; noise drawn from ``rng`` in sample order.

        Parameters
        ----------
        field_body : ndarray, (N, 3)
        rng : numpy.random.Generator, optional
            None: no noise.

        Returns
        -------
        ndarray, (N, 3)
        """
        raw = np.einsum("nk,jk->nj", np.asarray(field_body, float), self.soft_iron @ self.rotation)
        raw += self.hard_iron
        if rng is not None:
            raw += rng.standard_normal(raw.shape) * self.noise_ut
        np.clip(raw, -self.saturation, self.saturation, out=raw)
        if self.resolution:
            raw = np.round(raw / self.resolution) * self.resolution
        return raw

    def correct(self, raw: np.ndarray) -> np.ndarray:
        """The field in body (accelerometer) axes from raw readings: ``C^T W^-1 (raw - h)`` (N, 3).

        Parameters
        ----------
        raw : ndarray, (N, 3)

        Returns
        -------
        ndarray, (N, 3)
        """
        m = np.linalg.solve(self.soft_iron, (np.asarray(raw, float) - self.hard_iron).T)
        return (self.rotation.T @ m).T


def mag_from_options(options: dict[str, str], seed: int) -> MagTruth | None:
    """The magnetometer the ``sim://`` / ``simulate`` options ask for (``MAG_OPTIONS``), or None.

    ``mag=1`` gives the unit a random magnetometer (:meth:`MagTruth.random` of ``seed``);
    ``field=UT``, ``dip=DEG`` and ``declination=DEG`` set the local field and imply ``mag=1``
    unless ``mag=0`` is given.

    Parameters
    ----------
    options : dict
        Option name -> text.
    seed : int

    Returns
    -------
    MagTruth or None

    Raises
    ------
    ValueError
        A value that is not a number or is out of range, naming the option.
    """
    unknown = set(options) - set(MAG_OPTIONS)
    if unknown:
        raise ValueError(f"unknown magnetometer option(s) {', '.join(sorted(unknown))}")
    wanted = options.get("mag", "1").strip().lower() not in ("0", "false", "no", "")
    if not options or not wanted:
        return None
    values: dict[str, float] = {}
    for key, name in (("field", "magnitude_ut"), ("dip", "dip_deg"), ("declination", "declination_deg")):
        if key in options:
            try:
                values[name] = float(options[key])
            except ValueError:
                raise ValueError(f"{key}={options[key]!r} is not a number") from None
            if not np.isfinite(values[name]):
                raise ValueError(f"{key}={options[key]!r} is not a finite number")
    return MagTruth.random(seed, EarthField(**values))
