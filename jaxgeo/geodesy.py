"""WGS84 geodesy in pure JAX: geodetic <-> ECEF, local ENU frames, transverse Mercator / UTM.

Conventions (the same everywhere in jaxgeo):

- geodetic coordinates are ``(lon_deg, lat_deg, h_m)`` in that column order, ellipsoidal height;
- ECEF coordinates are metres, ``(X, Y, Z)``;
- projected coordinates are ``(easting_m, northing_m)``.

All functions broadcast over leading batch axes, are jittable and differentiable, and are
float64 (jaxgeo switches ``jax_enable_x64`` on when imported).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

WGS84_A_M = 6378137.0
"""Semi-major axis of the WGS84 ellipsoid (m)."""
WGS84_F = 1.0 / 298.257223563
"""Flattening of the WGS84 ellipsoid."""
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
"""First eccentricity squared."""
WGS84_EP2 = WGS84_E2 / (1.0 - WGS84_E2)
"""Second eccentricity squared."""
EARTH_MEAN_RADIUS_M = 6371008.8
GM_EARTH_M3_S2 = 398600.4415e9
"""Earth's gravitational parameter used by the along-track Kepler model (002_, m^3/s^2)."""
OMEGA_EARTH_RAD_S = 7.2921151467e-5
"""Earth's rotation rate (rad/s)."""

UTM_K0 = 0.9996
UTM_FALSE_EASTING_M = 500000.0
UTM_FALSE_NORTHING_SOUTH_M = 10000000.0


def geodetic_to_ecef(geodetic: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """``(lon_deg, lat_deg, h_m)`` on WGS84 -> ECEF ``(X, Y, Z)`` in metres."""
    geodetic = jnp.asarray(geodetic, dtype=float)
    lon = jnp.deg2rad(geodetic[..., 0])
    lat = jnp.deg2rad(geodetic[..., 1])
    h = geodetic[..., 2]
    return _ecef(jnp.sin(lon), jnp.cos(lon), jnp.sin(lat), jnp.cos(lat), h)


OFFSET_MAX_RAD = 0.2
"""Largest angular offset (rad, ~1270 km on the ground) for which :func:`sincos_near` is exact
to rounding (its first omitted Taylor term is below 3e-23)."""


def sincos_near(
    sin0: Float[ArrayLike, "*batch"],
    cos0: Float[ArrayLike, "*batch"],
    d: Float[ArrayLike, "*batch"],
) -> tuple[Array, Array]:
    """``(sin(a0 + d), cos(a0 + d))`` from ``sin(a0)``, ``cos(a0)`` and the offset ``d`` (rad)
    without trigonometric calls: the angle-addition formulas with the Taylor series of ``sin d``
    to ``d^13`` and of ``cos d`` to ``d^14``, exact to rounding for ``|d| <= OFFSET_MAX_RAD``
    (1e-12 relative at 1 rad). About 40 multiplications and additions: cheap even where XLA
    fuses them into every element of a consumer (a Jacobian of ECEF coordinates under ``vmap``
    evaluates each sine 9 times), unlike ``jnp.sin``."""
    d = jnp.asarray(d, dtype=float)
    d2 = d * d
    sd = d * (
        1 - d2 / 6 * (1 - d2 / 20 * (1 - d2 / 42 * (1 - d2 / 72 * (1 - d2 / 110 * (1 - d2 / 156)))))
    )
    cd = 1 - d2 / 2 * (
        1
        - d2 / 12 * (1 - d2 / 30 * (1 - d2 / 56 * (1 - d2 / 90 * (1 - d2 / 132 * (1 - d2 / 182)))))
    )
    return sin0 * cd + cos0 * sd, cos0 * cd - sin0 * sd


def geodetic_to_ecef_near(
    trig0: Float[ArrayLike, "*batch 4"],
    offset: Float[ArrayLike, "*batch 2"],
    h: Float[ArrayLike, "*batch"],
) -> Float[Array, "*batch 3"]:
    """:func:`geodetic_to_ecef` of the point ``(lon0 + dlon, lat0 + dlat, h)`` from
    ``trig0 = (sin lon0, cos lon0, sin lat0, cos lat0)`` and ``offset = (dlon, dlat)`` in
    radians (:func:`sincos_near`: exact to rounding for offsets up to ``OFFSET_MAX_RAD``)."""
    trig0 = jnp.asarray(trig0, dtype=float)
    offset = jnp.asarray(offset, dtype=float)
    sin_lon, cos_lon = sincos_near(trig0[..., 0], trig0[..., 1], offset[..., 0])
    sin_lat, cos_lat = sincos_near(trig0[..., 2], trig0[..., 3], offset[..., 1])
    return _ecef(sin_lon, cos_lon, sin_lat, cos_lat, jnp.asarray(h, dtype=float))


def lonlat_trig(lonlath: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 4"]:
    """``(sin lon, cos lon, sin lat, cos lat)`` of geodetic points (degrees)."""
    lonlath = jnp.asarray(lonlath, dtype=float)
    lon, lat = jnp.deg2rad(lonlath[..., 0]), jnp.deg2rad(lonlath[..., 1])
    return jnp.stack([jnp.sin(lon), jnp.cos(lon), jnp.sin(lat), jnp.cos(lat)], axis=-1)


def _ecef(sin_lon, cos_lon, sin_lat, cos_lat, h) -> Array:
    n = WGS84_A_M / jnp.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    x = (n + h) * cos_lat * cos_lon
    y = (n + h) * cos_lat * sin_lon
    z = (n * (1.0 - WGS84_E2) + h) * sin_lat
    return jnp.stack([x, y, z], axis=-1)


def ecef_to_geodetic(
    ecef: Float[ArrayLike, "*batch 3"], iterations: int = 4
) -> Float[Array, "*batch 3"]:
    """ECEF metres -> ``(lon_deg, lat_deg, h_m)`` on WGS84.

    Bowring's iteration on the parametric latitude; a fixed number of iterations (unrolled)
    keeps it differentiable to any order. Four iterations reach well below 1e-9 m from the
    ground to orbit altitudes. The height uses the form that is stable at every latitude.
    """
    ecef = jnp.asarray(ecef, dtype=float)
    x, y, z = ecef[..., 0], ecef[..., 1], ecef[..., 2]
    p = jnp.hypot(x, y)
    lon = jnp.arctan2(y, x)
    beta = jnp.arctan2(z, (1.0 - WGS84_F) * p)
    lat = beta
    for _ in range(iterations):
        lat = jnp.arctan2(
            z + WGS84_EP2 * WGS84_B_M * jnp.sin(beta) ** 3,
            p - WGS84_E2 * WGS84_A_M * jnp.cos(beta) ** 3,
        )
        beta = jnp.arctan2((1.0 - WGS84_F) * jnp.sin(lat), jnp.cos(lat))
    sin_lat, cos_lat = jnp.sin(lat), jnp.cos(lat)
    h = p * cos_lat + z * sin_lat - WGS84_A_M * jnp.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    return jnp.stack([jnp.rad2deg(lon), jnp.rad2deg(lat), h], axis=-1)


def enu_rotation(lon_deg: Float[ArrayLike, "*batch"], lat_deg: Float[ArrayLike, "*batch"]):
    """Rotation matrix ``R`` (rows east, north, up) with ``enu = R @ (ecef - origin_ecef)``."""
    lon = jnp.deg2rad(jnp.asarray(lon_deg, dtype=float))
    lat = jnp.deg2rad(jnp.asarray(lat_deg, dtype=float))
    sl, cl = jnp.sin(lon), jnp.cos(lon)
    sp, cp = jnp.sin(lat), jnp.cos(lat)
    zero = jnp.zeros_like(sl)
    east = jnp.stack([-sl, cl, zero], axis=-1)
    north = jnp.stack([-sp * cl, -sp * sl, cp], axis=-1)
    up = jnp.stack([cp * cl, cp * sl, sp], axis=-1)
    return jnp.stack([east, north, up], axis=-2)


def ecef_to_enu(
    ecef: Float[ArrayLike, "*batch 3"], origin: Float[ArrayLike, "3"]
) -> Float[Array, "*batch 3"]:
    """ECEF metres -> local east/north/up metres about the geodetic ``origin`` (lon, lat, h)."""
    origin = jnp.asarray(origin, dtype=float)
    rot = enu_rotation(origin[0], origin[1])
    d = jnp.asarray(ecef, dtype=float) - geodetic_to_ecef(origin)
    return jnp.einsum("ij,...j->...i", rot, d)


def enu_to_ecef(
    enu: Float[ArrayLike, "*batch 3"], origin: Float[ArrayLike, "3"]
) -> Float[Array, "*batch 3"]:
    """Local east/north/up metres about ``origin`` (lon, lat, h) -> ECEF metres."""
    origin = jnp.asarray(origin, dtype=float)
    rot = enu_rotation(origin[0], origin[1])
    return jnp.einsum("ji,...j->...i", rot, jnp.asarray(enu, dtype=float)) + geodetic_to_ecef(
        origin
    )


def geodetic_to_enu(
    geodetic: Float[ArrayLike, "*batch 3"], origin: Float[ArrayLike, "3"]
) -> Float[Array, "*batch 3"]:
    """Geodetic ``(lon_deg, lat_deg, h_m)`` -> local ENU metres about ``origin``."""
    return ecef_to_enu(geodetic_to_ecef(geodetic), origin)


def enu_to_geodetic(
    enu: Float[ArrayLike, "*batch 3"], origin: Float[ArrayLike, "3"]
) -> Float[Array, "*batch 3"]:
    """Local ENU metres about ``origin`` -> geodetic ``(lon_deg, lat_deg, h_m)``."""
    return ecef_to_geodetic(enu_to_ecef(enu, origin))


def metres_per_unit(
    lonlath: Float[ArrayLike, "*batch 3"], *, xp: Any = jnp
) -> Float[ArrayLike, "*batch 3"]:
    """Metres per degree of longitude, per degree of latitude, and per metre of height.

    At ``(lon_deg, lat_deg, h_m)``: ``(pi/180) (N + h) cos(lat)``, ``(pi/180) (M + h)`` and 1,
    with ``N``, ``M`` the WGS84 prime-vertical and meridian radii of curvature (m). Multiplying a
    small geodetic difference by it gives east, north, up metres. ``xp=numpy`` evaluates the same
    formula in numpy (host-side set-up without XLA dispatch; same numbers).
    """
    lonlath = xp.asarray(lonlath, dtype=float)
    lat = xp.deg2rad(lonlath[..., 1])
    h = lonlath[..., 2]
    w = xp.sqrt(1.0 - WGS84_E2 * xp.sin(lat) ** 2)
    n_radius = WGS84_A_M / w
    m_radius = WGS84_A_M * (1.0 - WGS84_E2) / w**3
    k = xp.pi / 180.0
    return xp.stack(
        [k * (n_radius + h) * xp.cos(lat), k * (m_radius + h), xp.ones_like(h)], axis=-1
    )


# --- transverse Mercator: Krueger series to order n^6 (Karney 2011, J. Geodesy 85:475) ------

_N = WGS84_F / (2.0 - WGS84_F)
_E = WGS84_E2**0.5
_RECTIFYING_RADIUS_M = WGS84_A_M / (1.0 + _N) * (1.0 + _N**2 / 4.0 + _N**4 / 64.0 + _N**6 / 256.0)


def _poly(coeffs: tuple[float, ...]) -> float:
    # coeffs[k] multiplies n^(k+1)
    return sum(c * _N ** (k + 1) for k, c in enumerate(coeffs))


_ALPHA = (
    _poly((1 / 2, -2 / 3, 5 / 16, 41 / 180, -127 / 288, 7891 / 37800)),
    _poly((0, 13 / 48, -3 / 5, 557 / 1440, 281 / 630, -1983433 / 1935360)),
    _poly((0, 0, 61 / 240, -103 / 140, 15061 / 26880, 167603 / 181440)),
    _poly((0, 0, 0, 49561 / 161280, -179 / 168, 6601661 / 7257600)),
    _poly((0, 0, 0, 0, 34729 / 80640, -3418889 / 1995840)),
    _poly((0, 0, 0, 0, 0, 212378941 / 319334400)),
)
_BETA = (
    _poly((1 / 2, -2 / 3, 37 / 96, -1 / 360, -81 / 512, 96199 / 604800)),
    _poly((0, 1 / 48, 1 / 15, -437 / 1440, 46 / 105, -1118711 / 3870720)),
    _poly((0, 0, 17 / 480, -37 / 840, -209 / 4480, 5569 / 90720)),
    _poly((0, 0, 0, 4397 / 161280, -11 / 504, -830251 / 7257600)),
    _poly((0, 0, 0, 0, 4583 / 161280, -108847 / 3991680)),
    _poly((0, 0, 0, 0, 0, 20648693 / 638668800)),
)


def _conformal_tan(tau):
    """tan(conformal latitude) from tan(geodetic latitude) (Karney 2011, eq. 7-9)."""
    sigma = jnp.sinh(_E * jnp.arctanh(_E * tau / jnp.sqrt(1.0 + tau**2)))
    return tau * jnp.sqrt(1.0 + sigma**2) - sigma * jnp.sqrt(1.0 + tau**2)


def tm_forward(
    lon_deg: Float[ArrayLike, "*batch"],
    lat_deg: Float[ArrayLike, "*batch"],
    lon0_deg: Float[ArrayLike, ""],
    k0: float = UTM_K0,
    false_easting_m: float = 0.0,
    false_northing_m: float = 0.0,
) -> Float[Array, "*batch 2"]:
    """Transverse Mercator on WGS84 (origin latitude 0): geodetic degrees -> (E, N) metres.

    Krueger series to order n^6: about 5 nm error within 3900 km of the central meridian.
    """
    lam = jnp.deg2rad(jnp.asarray(lon_deg, dtype=float) - lon0_deg)
    tau = jnp.tan(jnp.deg2rad(jnp.asarray(lat_deg, dtype=float)))
    tau_p = _conformal_tan(tau)
    xi_p = jnp.arctan2(tau_p, jnp.cos(lam))
    eta_p = jnp.arcsinh(jnp.sin(lam) / jnp.hypot(tau_p, jnp.cos(lam)))
    xi, eta = xi_p, eta_p
    for j, a in enumerate(_ALPHA, start=1):
        xi = xi + a * jnp.sin(2 * j * xi_p) * jnp.cosh(2 * j * eta_p)
        eta = eta + a * jnp.cos(2 * j * xi_p) * jnp.sinh(2 * j * eta_p)
    easting = false_easting_m + k0 * _RECTIFYING_RADIUS_M * eta
    northing = false_northing_m + k0 * _RECTIFYING_RADIUS_M * xi
    return jnp.stack([easting, northing], axis=-1)


def tm_inverse(
    easting_m: Float[ArrayLike, "*batch"],
    northing_m: Float[ArrayLike, "*batch"],
    lon0_deg: Float[ArrayLike, ""],
    k0: float = UTM_K0,
    false_easting_m: float = 0.0,
    false_northing_m: float = 0.0,
    iterations: int = 3,
) -> Float[Array, "*batch 2"]:
    """Inverse transverse Mercator: (E, N) metres -> ``(lon_deg, lat_deg)``."""
    scale = k0 * _RECTIFYING_RADIUS_M
    xi = (jnp.asarray(northing_m, dtype=float) - false_northing_m) / scale
    eta = (jnp.asarray(easting_m, dtype=float) - false_easting_m) / scale
    xi_p, eta_p = xi, eta
    for j, b in enumerate(_BETA, start=1):
        xi_p = xi_p - b * jnp.sin(2 * j * xi) * jnp.cosh(2 * j * eta)
        eta_p = eta_p - b * jnp.cos(2 * j * xi) * jnp.sinh(2 * j * eta)
    tau_p = jnp.sin(xi_p) / jnp.hypot(jnp.sinh(eta_p), jnp.cos(xi_p))
    lam = jnp.arctan2(jnp.sinh(eta_p), jnp.cos(xi_p))
    # Newton for tau from tau' (Karney 2011, eq. 19-21); converges in 2-3 steps.
    tau = tau_p
    for _ in range(iterations):
        tau_i = _conformal_tan(tau)
        dtau = (
            (tau_p - tau_i)
            / jnp.sqrt(1.0 + tau_i**2)
            * (1.0 + (1.0 - WGS84_E2) * tau**2)
            / ((1.0 - WGS84_E2) * jnp.sqrt(1.0 + tau**2))
        )
        tau = tau + dtau
    lon = jnp.rad2deg(lam) + lon0_deg
    lat = jnp.rad2deg(jnp.arctan(tau))
    return jnp.stack([lon, lat], axis=-1)


def utm_zone(lon_deg: float, lat_deg: float | None = None) -> int:
    """UTM zone number (1..60) of a longitude (standard 6-degree zones, no Norway exceptions)."""
    zone = int((float(lon_deg) + 180.0) // 6.0) % 60 + 1
    return zone


def utm_central_meridian(zone: int) -> float:
    """Central meridian (deg) of a UTM zone."""
    if not 1 <= int(zone) <= 60:
        raise ValueError(f"UTM zone must be in 1..60, got {zone}")
    return 6.0 * int(zone) - 183.0


def utm_epsg(zone: int, north: bool = True) -> int:
    """EPSG code of a WGS84 UTM zone (326zz north, 327zz south)."""
    utm_central_meridian(zone)
    return (32600 if north else 32700) + int(zone)


def geodetic_to_utm(
    geodetic: Float[ArrayLike, "*batch 3"], zone: int, north: bool = True
) -> Float[Array, "*batch 3"]:
    """``(lon_deg, lat_deg, h_m)`` -> ``(easting_m, northing_m, h_m)`` in a WGS84 UTM zone."""
    geodetic = jnp.asarray(geodetic, dtype=float)
    en = tm_forward(
        geodetic[..., 0],
        geodetic[..., 1],
        utm_central_meridian(zone),
        UTM_K0,
        UTM_FALSE_EASTING_M,
        0.0 if north else UTM_FALSE_NORTHING_SOUTH_M,
    )
    return jnp.concatenate([en, geodetic[..., 2:3]], axis=-1)


def utm_to_geodetic(
    utm: Float[ArrayLike, "*batch 3"], zone: int, north: bool = True
) -> Float[Array, "*batch 3"]:
    """``(easting_m, northing_m, h_m)`` in a WGS84 UTM zone -> ``(lon_deg, lat_deg, h_m)``."""
    utm = jnp.asarray(utm, dtype=float)
    ll = tm_inverse(
        utm[..., 0],
        utm[..., 1],
        utm_central_meridian(zone),
        UTM_K0,
        UTM_FALSE_EASTING_M,
        0.0 if north else UTM_FALSE_NORTHING_SOUTH_M,
    )
    return jnp.concatenate([ll, utm[..., 2:3]], axis=-1)
