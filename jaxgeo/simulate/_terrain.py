"""Smooth synthetic terrain: a sum of random plane waves, scaled to a chosen relief.

``h(lon, lat) = h_min + (h_max - h_min) * (raw - raw_min) / (raw_max - raw_min)`` with
``raw = sum_k a_k cos(k_k . (e, n) + phase_k)`` in local equirectangular metres ``(e, n)`` about
the centre. ``raw_min / raw_max`` are taken on a dense grid over the area the terrain was made for,
so heights there lie in ``[h_min, h_max]`` (to a few metres between grid nodes). Heights are
ellipsoidal (WGS84), in metres.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import geodesy


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

    def __init__(self, centre_lon_deg, centre_lat_deg, wavevectors_rad_m, amplitudes, phases_rad,
                 raw_min, raw_max, h_min_m, h_max_m):  # fmt: skip
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

    def _raw(self, lon, lat, xp):
        r = geodesy.EARTH_MEAN_RADIUS_M
        e = r * xp.cos(xp.deg2rad(self.centre_lat_deg)) * xp.deg2rad(lon - self.centre_lon_deg)
        n = r * xp.deg2rad(lat - self.centre_lat_deg)
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
        return self._scale(raw)

    def height_np(self, lonlat: ArrayLike) -> np.ndarray:
        """:meth:`height` in numpy (for deterministic point generation)."""
        lonlat = np.asarray(lonlat, dtype=float)
        return self._scale(self._raw(lonlat[..., 0], lonlat[..., 1], np))

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
        return {
            f.name: np.asarray(getattr(self, f.name)).tolist() for f in dataclasses.fields(self)
        }

    @classmethod
    def from_dict(cls, d: dict) -> Terrain:
        return cls(**d)
