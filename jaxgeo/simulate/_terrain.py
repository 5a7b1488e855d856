"""Smooth synthetic terrain: a sum of random plane waves, scaled to a chosen relief.

``h(lon, lat) = h_min + (h_max - h_min) * (raw - raw_min) / (raw_max - raw_min)`` with
``raw = sum_k a_k cos(k_k . (e, n) + phase_k)`` in local equirectangular metres ``(e, n)`` about
the centre. ``raw_min / raw_max`` are taken on a dense grid over the area the terrain was made for,
so heights there lie in ``[h_min, h_max]`` (to a few metres between grid nodes). Heights are
ellipsoidal (WGS84), in metres.

A terrain may carry height *changes* (:class:`TerrainChange`: another date of the same site, a
landslide bowl or a deposit): Gaussian bumps ``dh exp(-r^2 / (2 sigma^2))`` added to ``h`` (so
heights there may leave ``[h_min, h_max]`` by up to ``|dh|``).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import geodesy


@dataclasses.dataclass(frozen=True)
class TerrainChange:
    """A height change of the terrain (another date of the site): the Gaussian bump
    ``height_m * exp(-r^2 / (2 sigma_m^2))`` centred ``east_m, north_m`` (m) from the terrain's
    centre (``height_m < 0``: a bowl, e.g. a landslide's scar; ``> 0``: a deposit). The change
    is ``height_m`` at the centre, half of it at ``r = 1.18 sigma_m``, under 1 % beyond
    ``r = 3.03 sigma_m``."""

    height_m: float = -20.0
    east_m: float = 0.0
    north_m: float = 0.0
    sigma_m: float = 40.0

    def __post_init__(self):
        from ._scene import is_real, require

        for name in ("height_m", "east_m", "north_m", "sigma_m"):
            v = getattr(self, name)
            require(is_real(v) and np.isfinite(v), name, "be a finite number (m)", v)
        require(self.sigma_m > 0, "sigma_m", "be > 0 (m)", self.sigma_m)

    def as_row(self) -> list[float]:
        """``[east_m, north_m, sigma_m, height_m]``: a row of :attr:`Terrain.changes`."""
        return [float(self.east_m), float(self.north_m), float(self.sigma_m),
                float(self.height_m)]  # fmt: skip


class Terrain(eqx.Module):
    """A smooth height field over ``(lon_deg, lat_deg)``; see the module docstring.

    An equinox Module (a pytree), so it can be passed into jitted code.
    """

    centre_lon_deg: np.ndarray
    centre_lat_deg: np.ndarray
    wavevectors_rad_m: np.ndarray  # (k, 2) east, north
    amplitudes: np.ndarray  # (k,)
    phases_rad: np.ndarray  # (k,)
    raw_min: np.ndarray
    raw_max: np.ndarray
    h_min_m: np.ndarray
    h_max_m: np.ndarray
    changes: np.ndarray  # (c, 4) east_m, north_m, sigma_m, height_m (TerrainChange.as_row)

    def __init__(self, centre_lon_deg, centre_lat_deg, wavevectors_rad_m, amplitudes, phases_rad,
                 raw_min, raw_max, h_min_m, h_max_m, changes=()):  # fmt: skip
        # every field an array, so jitted code traces them (no recompilation per terrain)
        self.centre_lon_deg = np.asarray(centre_lon_deg, dtype=float)
        self.centre_lat_deg = np.asarray(centre_lat_deg, dtype=float)
        self.wavevectors_rad_m = np.asarray(wavevectors_rad_m, dtype=float).reshape(-1, 2)
        self.amplitudes = np.asarray(amplitudes, dtype=float)
        self.phases_rad = np.asarray(phases_rad, dtype=float)
        self.raw_min = np.asarray(raw_min, dtype=float)
        self.raw_max = np.asarray(raw_max, dtype=float)
        self.h_min_m = np.asarray(h_min_m, dtype=float)
        self.h_max_m = np.asarray(h_max_m, dtype=float)
        self.changes = np.asarray(changes, dtype=float).reshape(-1, 4)

    def _local(self, lon, lat, xp):
        """Local equirectangular ``(east, north)`` metres about the centre."""
        r = geodesy.EARTH_MEAN_RADIUS_M
        e = r * xp.cos(xp.deg2rad(self.centre_lat_deg)) * xp.deg2rad(lon - self.centre_lon_deg)
        return e, r * xp.deg2rad(lat - self.centre_lat_deg)

    def _raw(self, lon, lat, xp):
        e, n = self._local(lon, lat, xp)
        arg = (
            e[..., None] * self.wavevectors_rad_m[:, 0]
            + n[..., None] * self.wavevectors_rad_m[:, 1]
            + self.phases_rad
        )
        return xp.sum(self.amplitudes * xp.cos(arg), axis=-1)

    def height(self, lonlat: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """Ellipsoidal height (m) at ``(lon_deg, lat_deg)`` (jax or numpy input; jnp out)."""
        lonlat = jnp.asarray(lonlat, dtype=float)
        raw = self._raw(lonlat[..., 0], lonlat[..., 1], jnp)
        return self._scale(raw) + self._change(lonlat[..., 0], lonlat[..., 1], jnp)

    def height_np(self, lonlat: ArrayLike) -> np.ndarray:
        """:meth:`height` in numpy (for deterministic point generation)."""
        lonlat = np.asarray(lonlat, dtype=float)
        lon, lat = lonlat[..., 0], lonlat[..., 1]
        return self._scale(self._raw(lon, lat, np)) + self._change(lon, lat, np)

    def change_np(self, lonlat: ArrayLike) -> np.ndarray:
        """The height added by :attr:`changes` at ``(lon_deg, lat_deg)`` (m; 0 without any)."""
        lonlat = np.asarray(lonlat, dtype=float)
        return self._change(lonlat[..., 0], lonlat[..., 1], np)

    def with_changes(self, *changes: TerrainChange) -> Terrain:
        """This terrain with ``changes`` added to those it has (another date of the site)."""
        rows = np.concatenate([self.changes, np.asarray([c.as_row() for c in changes],
                                                        dtype=float).reshape(-1, 4)])  # fmt: skip
        return dataclasses.replace(self, changes=rows)

    def _change(self, lon, lat, xp):
        e, n = self._local(lon, lat, xp)
        c = self.changes
        r2 = (e[..., None] - c[:, 0]) ** 2 + (n[..., None] - c[:, 1]) ** 2
        return xp.sum(c[:, 3] * xp.exp(-r2 / (2.0 * c[:, 2] ** 2)), axis=-1)

    def _scale(self, raw):
        u = (raw - self.raw_min) / (self.raw_max - self.raw_min)
        return self.h_min_m + (self.h_max_m - self.h_min_m) * u

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        corners_lonlat: ArrayLike,
        h_range_m: tuple[float, float] = (0.0, 1260.0),
        n_waves: int = 8,
        wavelength_range_m: tuple[float, float] = (4000.0, 40000.0),
        fit_relief: bool = True,
    ) -> Terrain:
        """Random terrain over the lon/lat bounding box of ``corners_lonlat`` ``(k, 2)``.

        ``fit_relief``: stretch the heights found on a 201 x 201 grid over the box to ``h_range_m``
        (a scene); otherwise use the bounds ``+-sum(amplitudes)`` (a long strip, which a grid
        cannot resolve), so heights stay inside ``h_range_m`` without reaching its ends.
        """
        corners = np.asarray(corners_lonlat, dtype=float)
        lo, hi = corners.min(0), corners.max(0)
        centre = 0.5 * (lo + hi)
        wl = np.exp(rng.uniform(*np.log(wavelength_range_m), n_waves))
        direction = rng.uniform(0.0, 2.0 * np.pi, n_waves)
        k = (2.0 * np.pi / wl)[:, None] * np.stack([np.cos(direction), np.sin(direction)], -1)
        amp = wl / wl.max() * rng.uniform(0.5, 1.0, n_waves)  # long waves carry the relief
        phase = rng.uniform(0.0, 2.0 * np.pi, n_waves)
        proto = cls(
            float(centre[0]),
            float(centre[1]),
            k,
            amp,
            phase,
            0.0,
            1.0,
            *(float(v) for v in h_range_m),
        )
        if not fit_relief:
            bound = float(np.sum(amp))
            return dataclasses.replace(proto, raw_min=-bound, raw_max=bound)
        lon, lat = np.meshgrid(np.linspace(lo[0], hi[0], 201), np.linspace(lo[1], hi[1], 201))
        raw = proto._raw(lon, lat, np)
        return dataclasses.replace(proto, raw_min=float(raw.min()), raw_max=float(raw.max()))

    def to_dict(self) -> dict:
        """The fields as JSON lists; ``changes`` only when there are any (a single date's
        ``truth.json`` is what it was before changes existed, byte for byte)."""
        out = {f.name: np.asarray(getattr(self, f.name)).tolist() for f in dataclasses.fields(self)}
        if not len(self.changes):
            del out["changes"]
        return out

    @classmethod
    def from_dict(cls, d: dict) -> Terrain:
        return cls(**d)
