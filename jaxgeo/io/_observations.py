"""The observation data types the upper layers share: ground points and image measurements.

Plain frozen containers of numpy arrays (host-side, built once per adjustment), checked on
construction. :mod:`jaxgeo.io._tables` reads and writes them as CSV; the bundle adjustment and the
strip pipeline take them as input.

Conventions: ``lonlath`` ``(lon_deg, lat_deg, h_m)`` on WGS84 (ellipsoidal height); ``sigma_m``
a priori standard deviations east, north, up in metres; ``xy`` ``(x, y) = (column, row)`` in
pixels, integer values at pixel centres, ``(0, 0)`` the centre of the first pixel; ``sigma_px``
a priori standard deviation of each image coordinate in pixels.
"""

from __future__ import annotations

import dataclasses

import numpy as np

ROLES = ("gcp", "check")
"""Roles of a ground point: control (``gcp``) or independent check point (``check``)."""


@dataclasses.dataclass(frozen=True)
class GroundPoints:
    """Ground points: ``ids``, ``lonlath`` (n, 3) deg/deg/m, ``role``, ``sigma_m`` (n, 3) ENU m."""

    ids: tuple[str, ...]
    lonlath: np.ndarray
    role: tuple[str, ...]
    sigma_m: np.ndarray

    def __post_init__(self):
        n = len(self.ids)
        if self.lonlath.shape != (n, 3) or self.sigma_m.shape != (n, 3) or len(self.role) != n:
            raise ValueError("GroundPoints: ids, lonlath (n,3), role and sigma_m (n,3) disagree")

    def __len__(self) -> int:
        return len(self.ids)

    def select(self, role: str) -> GroundPoints:
        """The points with this role (``gcp`` or ``check``)."""
        keep = [i for i, r in enumerate(self.role) if r == role]
        return GroundPoints(
            tuple(self.ids[i] for i in keep),
            self.lonlath[keep],
            tuple(self.role[i] for i in keep),
            self.sigma_m[keep],
        )

    def with_roles(self, roles: dict[str, str]) -> GroundPoints:
        """A copy with the role of some points changed (``{id: role}``)."""
        for pid, r in roles.items():
            if r not in ROLES:
                raise ValueError(f"role of point {pid!r} must be one of {ROLES}, got {r!r}")
            if pid not in self.ids:
                raise KeyError(f"no ground point {pid!r}")
        return dataclasses.replace(
            self, role=tuple(roles.get(i, r) for i, r in zip(self.ids, self.role, strict=True))
        )


@dataclasses.dataclass(frozen=True)
class Observations:
    """Image measurements: ``point_ids``, ``images``, ``xy`` (m, 2) px, ``sigma_px`` (m,)."""

    point_ids: tuple[str, ...]
    images: tuple[str, ...]
    xy: np.ndarray
    sigma_px: np.ndarray

    def __post_init__(self):
        m = len(self.point_ids)
        if self.xy.shape != (m, 2) or self.sigma_px.shape != (m,) or len(self.images) != m:
            raise ValueError("Observations: point_ids, images, xy (m,2) and sigma_px (m,) disagree")

    def __len__(self) -> int:
        return len(self.point_ids)


__all__ = ["ROLES", "GroundPoints", "Observations"]
