"""The 3D affine model: a parallel projection of object space onto the image.

Equation 1 of 000_5aba1cb50921f3c6.txt (Fraser & Yamakawa 2004)::

    x = a1 X + a2 Y + a3 Z + a4
    y = a5 X + a6 Y + a7 Z + a8

with ``(X, Y, Z)`` object coordinates in one of three spaces (``space``):

- ``"geocentric"``: ECEF metres;
- ``"geographic"``: ``(lon_deg, lat_deg, h_m)``;
- ``"utm"``: ``(easting_m, northing_m, h_m)`` in a WGS84 UTM zone (the space the paper finds
  best, because the affine model assumes a parallel imaging plane).

Conditioning. The eight stored parameters ``params`` act on *normalised* coordinates:
``X_n = (X - object_offset) / object_scale`` per axis and ``x = image_offset + image_scale *
x_n``. The offsets/scales are static (chosen by :meth:`Affine3D.fit`: the GCP centroid and
standard deviation per axis, the image centroid and spread), so ``params`` are O(1) and the
normal equations of any later adjustment are well conditioned. The paper's ``a1..a8`` in the
object-space units are :meth:`Affine3D.raw_parameters`; :meth:`Affine3D.from_raw` goes back.

``project`` takes geodetic ground ``(lon_deg, lat_deg, h_m)`` whatever the object space (the
conversion uses :mod:`jaxgeo.geodesy`, so everything stays differentiable). ``localize`` at a
fixed height is closed form in the geographic and UTM spaces (a 2 x 2 linear system) and the
shared Newton iteration in the geocentric space.
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PyTree

from .. import geodesy
from ._base import AbstractSensorModel, all_inexact

ObjectSpace = Literal["geocentric", "geographic", "utm"]
SPACES = ("geocentric", "geographic", "utm")

COPLANAR_RTOL = 1e-4
"""GCPs are (near-)coplanar when the thickness / extent of their centred metric object
coordinates (smallest / largest singular value) is below this: e.g. points at one height over
10 km are ~5e-5 thick in geocentric space from the Earth's curvature alone."""


def to_object(
    ground: Float[ArrayLike, "*batch 3"], space: str, zone: int | None, north: bool
) -> Float[Array, "*batch 3"]:
    """Geodetic ``(lon_deg, lat_deg, h_m)`` -> object coordinates of ``space``."""
    ground = jnp.asarray(ground, dtype=float)
    if space == "geocentric":
        return geodesy.geodetic_to_ecef(ground)
    if space == "geographic":
        return ground
    if space == "utm":
        return geodesy.geodetic_to_utm(ground, zone, north)
    raise ValueError(f"unknown object space {space!r}; expected one of {SPACES}")


class Affine3D(AbstractSensorModel):
    """3D affine sensor model (8 parameters) in a geocentric, geographic or UTM object space.

    Fields:
        params: ``(8,)`` the normalised-space ``(a1, ..., a8)`` (the adjustable leaf).
        space: object space, ``"geocentric" | "geographic" | "utm"`` (static).
        zone, north: the UTM zone and hemisphere when ``space == "utm"`` (static).
        object_offset, object_scale: per-axis normalisation of object coordinates (static).
        image_offset, image_scale: normalisation of ``(x, y)`` pixels (static).
        ground_reference: ``(lon_deg, lat_deg, h_m)`` inside the scene (static).
    """

    params: Float[Array, "8"]
    space: str = eqx.field(static=True)
    zone: int | None = eqx.field(static=True)
    north: bool = eqx.field(static=True)
    object_offset: tuple[float, float, float] = eqx.field(static=True)
    object_scale: tuple[float, float, float] = eqx.field(static=True)
    image_offset: tuple[float, float] = eqx.field(static=True)
    image_scale: tuple[float, float] = eqx.field(static=True)
    ground_reference: tuple[float, float, float] = eqx.field(static=True)

    def __init__(
        self,
        params: Float[ArrayLike, "8"],
        space: ObjectSpace,
        ground_reference: ArrayLike,
        zone: int | None = None,
        north: bool = True,
        object_offset: ArrayLike = (0.0, 0.0, 0.0),
        object_scale: ArrayLike = (1.0, 1.0, 1.0),
        image_offset: ArrayLike = (0.0, 0.0),
        image_scale: ArrayLike = (1.0, 1.0),
    ):
        if space not in SPACES:
            raise ValueError(f"unknown object space {space!r}; expected one of {SPACES}")
        if space == "utm":
            if zone is None:
                raise ValueError("Affine3D in 'utm' object space needs a zone (1..60)")
            geodesy.utm_central_meridian(zone)  # validates the zone
        self.params = jnp.asarray(params, dtype=float)
        self.space = space
        self.zone = int(zone) if zone is not None else None
        self.north = bool(north)
        self.object_offset = tuple(float(v) for v in np.ravel(object_offset))
        self.object_scale = tuple(float(v) for v in np.ravel(object_scale))
        self.image_offset = tuple(float(v) for v in np.ravel(image_offset))
        self.image_scale = tuple(float(v) for v in np.ravel(image_scale))
        self.ground_reference = tuple(float(v) for v in np.ravel(ground_reference))

    def __check_init__(self):
        if self.params.shape[-1:] != (8,):
            raise ValueError(f"Affine3D.params must have shape (..., 8), got {self.params.shape}")
        for name, n in (
            ("object_offset", 3),
            ("object_scale", 3),
            ("image_offset", 2),
            ("image_scale", 2),
            ("ground_reference", 3),
        ):
            if len(getattr(self, name)) != n:
                raise ValueError(f"Affine3D.{name} must have {n} values, got {getattr(self, name)}")
        if any(s == 0.0 for s in self.object_scale + self.image_scale):
            raise ValueError("Affine3D normalisation scales must be non-zero")

    # --- the model ---------------------------------------------------------------------

    def normalize_object(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """Geodetic ground -> normalised object coordinates ``X_n``."""
        obj = to_object(ground, self.space, self.zone, self.north)
        return (obj - jnp.asarray(self.object_offset)) / jnp.asarray(self.object_scale)

    def project(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """Ground ``(lon_deg, lat_deg, h_m)`` -> image ``(x, y)`` px (eq. 1)."""
        ground = jnp.asarray(ground, dtype=float)
        if ground.shape[-1:] != (3,):
            raise ValueError(f"ground coordinates need a last axis of size 3, got {ground.shape}")
        n = self.normalize_object(ground)
        a = self.params.reshape(2, 4)
        xn = jnp.einsum("...k,ik->...i", n, a[:, :3]) + a[:, 3]
        return jnp.asarray(self.image_offset) + jnp.asarray(self.image_scale) * xn

    def reference_ground(self) -> Float[Array, "3"]:
        return jnp.asarray(self.ground_reference)

    def _localize_point(self, image, h, guess):
        """Closed form (a 2 x 2 linear system) in the geographic and UTM spaces, where ``h`` is
        an object coordinate; the shared Newton (``guess`` used) in geocentric space."""
        if self.space == "geocentric":
            return super()._localize_point(image, h, guess)
        off, scale = jnp.asarray(self.object_offset), jnp.asarray(self.object_scale)
        xn = (image - jnp.asarray(self.image_offset)) / jnp.asarray(self.image_scale)
        hn = (h - off[2]) / scale[2]
        a = self.params.reshape(2, 4)
        rhs = xn - a[:, 2] * hn[..., None] - a[:, 3]
        det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
        un = (a[1, 1] * rhs[..., 0] - a[0, 1] * rhs[..., 1]) / det
        vn = (a[0, 0] * rhs[..., 1] - a[1, 0] * rhs[..., 0]) / det
        obj = jnp.stack([off[0] + scale[0] * un, off[1] + scale[1] * vn, h], axis=-1)
        if self.space == "utm":
            return geodesy.utm_to_geodetic(obj, self.zone, self.north)
        return obj

    def adjustable_filter(self) -> PyTree[bool]:
        """The eight parameters (every floating-point leaf)."""
        return all_inexact(self)

    def required_gcps(self, dynamic: PyTree) -> tuple[int, str] | None:
        """Four non-coplanar GCPs when the parameters are adjusted."""
        if jax.tree.leaves(dynamic):
            return 4, "the 3D affine model (8 parameters, non-coplanar GCPs)"
        return None

    # --- the paper's parameters --------------------------------------------------------

    def raw_parameters(self) -> Float[Array, "8"]:
        """The paper's ``(a1, ..., a8)`` of eq. 1 in object-space units (m or deg) and pixels."""
        a = self.params.reshape(2, 4)
        off, s = jnp.asarray(self.object_offset), jnp.asarray(self.object_scale)
        io, iscale = jnp.asarray(self.image_offset), jnp.asarray(self.image_scale)
        lin = iscale[:, None] * a[:, :3] / s
        const = io + iscale * (a[:, 3] - jnp.sum(a[:, :3] * off / s, axis=-1))
        return jnp.concatenate([lin, const[:, None]], axis=-1).reshape(8)

    @classmethod
    def from_raw(
        cls,
        raw: Float[ArrayLike, "8"],
        space: ObjectSpace,
        ground_reference: ArrayLike,
        zone: int | None = None,
        north: bool = True,
    ) -> Affine3D:
        """Build from the paper's ``(a1, ..., a8)`` (no normalisation: offsets 0, scales 1)."""
        return cls(raw, space, ground_reference, zone=zone, north=north)

    # --- estimation --------------------------------------------------------------------

    @classmethod
    def fit(
        cls,
        ground: Float[ArrayLike, "n 3"],
        image: Float[ArrayLike, "n 2"],
        space: ObjectSpace = "utm",
        zone: int | None = None,
        north: bool | None = None,
        coplanar_rtol: float = COPLANAR_RTOL,
    ) -> Affine3D:
        """Direct linear least-squares estimate of the 8 parameters from ``n >= 4`` GCPs.

        ``ground`` ``(n, 3)`` geodetic, ``image`` ``(n, 2)`` px. ``zone``/``north`` default to
        those of the GCP centroid. Raises ``ValueError`` for fewer than 4 GCPs, non-finite
        values, or (near-)coplanar GCPs (see :data:`COPLANAR_RTOL`); the message names the
        count.
        """
        ground = np.asarray(ground, dtype=float)
        image = np.asarray(image, dtype=float)
        if ground.ndim != 2 or ground.shape[1] != 3:
            raise ValueError(f"Affine3D.fit: ground must have shape (n, 3), got {ground.shape}")
        if image.shape != (ground.shape[0], 2):
            raise ValueError(
                f"Affine3D.fit: image must have shape ({ground.shape[0]}, 2), got {image.shape}"
            )
        n = ground.shape[0]
        if n < 4:
            raise ValueError(
                f"Affine3D.fit needs at least 4 non-coplanar GCPs to determine its 8 "
                f"parameters, got {n}"
            )
        bad = ~(np.isfinite(ground).all(axis=1) & np.isfinite(image).all(axis=1))
        if bad.any():
            where = np.flatnonzero(bad).tolist()
            raise ValueError(f"Affine3D.fit: non-finite GCP(s) at index {where}")
        if space not in SPACES:
            raise ValueError(f"unknown object space {space!r}; expected one of {SPACES}")
        centroid = ground.mean(axis=0)
        if space == "utm":
            zone = geodesy.utm_zone(centroid[0]) if zone is None else int(zone)
            north = bool(centroid[1] >= 0.0) if north is None else bool(north)
        north = True if north is None else north

        # (near-)coplanarity: centred object coordinates in metres (degrees scaled by the local
        # radii in geographic space), normalised by their extent; thickness / extent is the
        # ratio of the smallest to the largest singular value (0 for coplanar points)
        obj = np.asarray(to_object(ground, space, zone, north))
        metric = obj - obj.mean(axis=0)
        if space == "geographic":
            k = np.pi / 180.0 * geodesy.EARTH_MEAN_RADIUS_M
            metric = metric * np.array([k * np.cos(np.deg2rad(centroid[1])), k, 1.0])
        sv = np.linalg.svd(metric, compute_uv=False)
        ratio = sv[2] / sv[0] if sv[0] > 0.0 else 0.0
        if not ratio >= coplanar_rtol:
            raise ValueError(
                f"Affine3D.fit: the {n} GCPs are (near-)coplanar in {space} space "
                f"(thickness/extent = {ratio:.2e} < {coplanar_rtol:.0e}); at least 4 "
                "non-coplanar GCPs are needed"
            )

        off = obj.mean(axis=0)
        scale = obj.std(axis=0)
        img_off = image.mean(axis=0)
        img_scale = np.maximum(image.std(axis=0), 1.0)
        design = np.concatenate([(obj - off) / scale, np.ones((n, 1))], axis=1)
        coef, *_ = np.linalg.lstsq(design, (image - img_off) / img_scale, rcond=None)
        params = coef.T.reshape(8)  # rows: x then y; columns: X, Y, Z, 1
        return cls(
            params,
            space,
            centroid,
            zone=zone,
            north=north,
            object_offset=off,
            object_scale=scale,
            image_offset=img_off,
            image_scale=img_scale,
        )
