"""A procedural ground texture: albedo as a pure function of position, for scenes of any size.

The raster texture of :mod:`._render` holds the whole footprint in memory (quadratic in the
image size); this one is evaluated where a pixel's line of sight meets the terrain, so rendering
a scene block by block needs memory independent of its size. On the local equirectangular plane
of the terrain's centre (east, north metres, as :class:`~jaxgeo.simulate.Terrain`):

- fields: a Voronoi partition of jittered seeds on a ``field_size_m`` grid (cellular noise), each
  field its own brightness (0.25..0.75) and furrows (a sinusoid of 0.06, period 3..10 m, random
  direction and phase);
- field boundaries: a third are bright tracks (0.85), a third dark hedges (0.12), the rest
  unmarked, 2..6 m wide;
- band-limited value noise (quintic interpolation of lattice values), one octave per feature size
  in ``octaves_m``, of standard deviation about 0.09 in all.

Every random value is an integer hash (32-bit, ``lowbias32``) of the texture's key and a lattice
cell, so the texture is deterministic in the key and the same wherever and in whatever order it
is sampled. Features are at least ``min(octaves_m)`` (2 m by default: three pixels of a 0.66 m
GSD), so 2 x 2 supersampling renders them without aliasing; field edges are sharp, as in nature.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, UInt32

from .. import geodesy

NOISE_STD = 0.09
"""Standard deviation of the summed noise octaves (albedo units)."""
_VALUE_NOISE_STD = 0.45
"""Standard deviation of one octave of value noise with lattice values uniform in [-1, 1]
(measured: 0.45 with quintic interpolation)."""


def _mix(h: Array) -> Array:
    """``lowbias32`` finaliser (Wellons): a 32-bit avalanche of ``h`` (uint32)."""
    h = h ^ (h >> 16)
    h = h * jnp.uint32(0x7FEB352D)
    h = h ^ (h >> 15)
    h = h * jnp.uint32(0x846CA68B)
    return h ^ (h >> 16)


def _cell_hash(key: Array, salt: int, i: Array, j: Array) -> Array:
    """One uint32 hash of ``key``, a salt and the lattice cell ``(i, j)`` (int32; wraps)."""
    u = jnp.uint32
    h = key ^ u(salt * 0x27D4EB2F % 2**32)
    h = h + i.astype(u) * u(0x8DA6B343) + j.astype(u) * u(0xD8163841)
    return _mix(h)


def _bits(h: Array, shift: int, n: int = 8) -> Array:
    """``n`` bits of ``h`` from bit ``shift`` as a float32 in [0, 1)."""
    return ((h >> shift) & jnp.uint32((1 << n) - 1)).astype(jnp.float32) * (1.0 / (1 << n))


def _smoothstep(e0, e1, x):
    t = jnp.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _value_noise(key: Array, octave: int, u: Array, v: Array) -> Array:
    """Value noise of unit lattice at ``(u, v)`` (float32): lattice values uniform in [-1, 1]
    (16-bit), quintic interpolation."""
    i, j = jnp.floor(u), jnp.floor(v)
    fu, fv = u - i, v - j
    i, j = i.astype(jnp.int32), j.astype(jnp.int32)

    def corner(di, dj):
        return 2.0 * _bits(_cell_hash(key, octave, i + di, j + dj), 0, 16) - 1.0

    su = fu * fu * fu * (fu * (fu * 6.0 - 15.0) + 10.0)
    sv = fv * fv * fv * (fv * (fv * 6.0 - 15.0) + 10.0)
    top = corner(0, 0) * (1 - su) + corner(1, 0) * su
    bottom = corner(0, 1) * (1 - su) + corner(1, 1) * su
    return top * (1 - sv) + bottom * sv


class ProceduralTexture(eqx.Module):
    """Albedo (0.02..1) as a function of ``(lon, lat)`` (module docstring); an equinox Module,
    so it passes into jitted code. ``key`` is a uint32 array drawn from the scene's seed."""

    centre_lon_deg: Float[Array, ""]
    centre_lat_deg: Float[Array, ""]
    key: UInt32[Array, ""]
    field_size_m: Float[Array, ""]
    octaves_m: tuple[float, ...] = eqx.field(static=True, default=(2.0, 4.0, 8.0, 16.0, 32.0))

    def __init__(self, centre_lon_deg, centre_lat_deg, key, field_size_m=60.0,
                 octaves_m=(2.0, 4.0, 8.0, 16.0, 32.0)):  # fmt: skip
        self.centre_lon_deg = jnp.asarray(centre_lon_deg, dtype=float)
        self.centre_lat_deg = jnp.asarray(centre_lat_deg, dtype=float)
        self.key = jnp.asarray(np.uint32(int(key) % 2**32))
        self.field_size_m = jnp.asarray(field_size_m, dtype=float)
        self.octaves_m = tuple(float(v) for v in octaves_m)

    def local(self, lonlat: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch 2"]:
        """``(lon, lat)`` deg -> local ``(east, north)`` m (the terrain's equirectangular plane)."""
        lonlat = jnp.asarray(lonlat, dtype=float)
        r = geodesy.EARTH_MEAN_RADIUS_M
        e = (
            r
            * jnp.cos(jnp.deg2rad(self.centre_lat_deg))
            * jnp.deg2rad(lonlat[..., 0] - self.centre_lon_deg)
        )
        n = r * jnp.deg2rad(lonlat[..., 1] - self.centre_lat_deg)
        return jnp.stack([e, n], axis=-1)

    def sample(self, lonlat: Float[ArrayLike, "*batch 2"]) -> Float[Array, "*batch"]:
        """Albedo at ``(lon, lat)`` deg (float64; computed in float32 from local metres,
        which resolve 1 mm over +-100 km)."""
        en = self.local(lonlat).astype(jnp.float32)
        e, n = en[..., 0], en[..., 1]
        key = self.key
        f32 = jnp.float32
        # fields: nearest and second-nearest jittered seed among the 3 x 3 neighbouring cells
        size = self.field_size_m.astype(f32)
        pu, pv = e / size, n / size
        cu, cv = jnp.floor(pu).astype(jnp.int32), jnp.floor(pv).astype(jnp.int32)
        inf = jnp.full(e.shape, jnp.inf, f32)
        d1, d2 = inf, inf
        zero = jnp.zeros(e.shape, f32)
        u1 = v1 = u2 = v2 = zero
        id1 = id2 = jnp.zeros(e.shape, jnp.uint32)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                i, j = cu + di, cv + dj
                h = _cell_hash(key, 1, i, j)
                su = i.astype(f32) + 0.1 + 0.8 * _bits(h, 0, 16)
                sv = j.astype(f32) + 0.1 + 0.8 * _bits(h, 16, 16)
                d = (pu - su) ** 2 + (pv - sv) ** 2
                first = d < d1
                second = ~first & (d < d2)
                d2 = jnp.where(first, d1, jnp.where(second, d, d2))
                u2 = jnp.where(first, u1, jnp.where(second, su, u2))
                v2 = jnp.where(first, v1, jnp.where(second, sv, v2))
                id2 = jnp.where(first, id1, jnp.where(second, h, id2))
                d1, u1, v1 = (jnp.where(first, a, b) for a, b in ((d, d1), (su, u1), (sv, v1)))
                id1 = jnp.where(first, h, id1)
        # distance (m) to the bisector of the two nearest seeds: the field boundary
        sep = jnp.hypot(u2 - u1, v2 - v1)
        edge_m = (d2 - d1) / (2.0 * jnp.maximum(sep, 1e-6)) * size
        p = _mix(id1 ^ key)  # the field's own parameters, 8 bits each
        base = 0.25 + 0.5 * _bits(p, 0)
        angle = jnp.pi * _bits(p, 8)
        period = 3.0 + 7.0 * _bits(p, 16)
        phase = 2.0 * jnp.pi * _bits(p, 24)
        along = e * jnp.cos(angle) + n * jnp.sin(angle)
        albedo = base + 0.06 * jnp.sin(2.0 * jnp.pi * along / period + phase)
        # noise octaves
        noise = zero
        for k, octave in enumerate(self.octaves_m):
            noise = noise + _value_noise(key, 2 + k, e / octave, n / octave)
        scale = NOISE_STD / (_VALUE_NOISE_STD * np.sqrt(len(self.octaves_m)))
        albedo = albedo + scale * noise
        # boundaries: a symmetric hash of the two fields chooses track, hedge or nothing
        pair = _mix(jnp.minimum(id1, id2) * jnp.uint32(0x9E3779B1) + jnp.maximum(id1, id2))
        kind = _bits(pair, 0)
        width = 2.0 + 4.0 * _bits(pair, 8)
        line = 1.0 - _smoothstep(0.5 * width - 0.5, 0.5 * width + 0.5, edge_m)
        value = jnp.where(kind < 0.33, 0.85, 0.12)
        line = jnp.where(kind < 0.66, line, 0.0)
        albedo = albedo * (1.0 - line) + value * line
        return jnp.clip(albedo, 0.02, 1.0).astype(float)

    def to_dict(self) -> dict:
        return {
            "centre_lon_deg": float(self.centre_lon_deg),
            "centre_lat_deg": float(self.centre_lat_deg),
            "key": int(self.key),
            "field_size_m": float(self.field_size_m),
            "octaves_m": list(self.octaves_m),
        }

    @classmethod
    def from_dict(cls, d: dict) -> ProceduralTexture:
        return cls(d["centre_lon_deg"], d["centre_lat_deg"], int(d["key"]), d["field_size_m"],
                   tuple(d["octaves_m"]))  # fmt: skip
