"""The rational function model (RFM / RPC), as vendors deliver it.

``x = samp_off + samp_scale * Num_x(L, P, H) / Den_x(L, P, H)`` and likewise ``y`` with the line
polynomials, where ``L, P, H`` are longitude, latitude and ellipsoidal height normalised by their
offsets and scales (001_5627e94f1608fac0.txt eq. 1-2). Coefficients are stored in the RPC00B term
order (GDAL, DigitalGlobe, Pleiades, Cartosat); RPC00A files are permuted on the way in and out.
Image coordinates follow jaxgeo's convention, which is the RPC standard: ``(x, y) = (samp, line)``,
integer values at pixel centres, ``(0, 0)`` the centre of the first pixel.
"""

from __future__ import annotations

from typing import Literal

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, PyTree

from .._runtime.arrays import device_array
from ._base import AbstractSensorModel, nothing
from ._rpc_eval import (
    is_concrete,
    localize_concrete,
    localize_traced,
    project_concrete,
    project_stacked,
)

TermOrder = Literal["RPC00B", "RPC00A"]

RPC00B_TERMS = (
    "1", "L", "P", "H", "LP", "LH", "PH", "LL", "PP", "HH",
    "PLH", "LLL", "LPP", "LHH", "LLP", "PPP", "PHH", "LLH", "PPH", "HHH",
)  # fmt: skip
"""Monomials of the RPC00B order (NITF STDI-0002, GDAL): L = lon, P = lat, H = height."""
RPC00A_TERMS = (
    "1", "L", "P", "H", "LP", "LH", "PH", "LPH", "LL", "PP",
    "HH", "LLL", "LLP", "LLH", "LPP", "PPP", "PPH", "LHH", "PHH", "HHH",
)  # fmt: skip
"""Monomials of the RPC00A order (003_a7d3ea260371d8c5.txt eq. 6 with X = L, Y = P, Z = H)."""


def _canonical(term: str) -> str:
    return "".join(sorted(term))


_A_INDEX = {_canonical(t): i for i, t in enumerate(RPC00A_TERMS)}
A_TO_B = np.array([_A_INDEX[_canonical(t)] for t in RPC00B_TERMS])
"""``coeffs_b = coeffs_a[A_TO_B]``."""
B_TO_A = np.argsort(A_TO_B)
"""``coeffs_a = coeffs_b[B_TO_A]``."""


def to_rpc00b(coeffs: ArrayLike, order: TermOrder) -> np.ndarray:
    """Permute coefficients (last axis of 20) from ``order`` into RPC00B order."""
    coeffs = np.asarray(coeffs, dtype=float)
    if order == "RPC00B":
        return coeffs
    if order == "RPC00A":
        return coeffs[..., A_TO_B]
    raise ValueError(f"unknown RPC term order {order!r}; expected 'RPC00A' or 'RPC00B'")


def from_rpc00b(coeffs: ArrayLike, order: TermOrder) -> np.ndarray:
    """Permute RPC00B coefficients (last axis of 20) into ``order``."""
    coeffs = np.asarray(coeffs, dtype=float)
    if order == "RPC00B":
        return coeffs
    if order == "RPC00A":
        return coeffs[..., B_TO_A]
    raise ValueError(f"unknown RPC term order {order!r}; expected 'RPC00A' or 'RPC00B'")


def _monomial_list(normalized: Float[Array, "*batch 3"]) -> list[Float[Array, "*batch"]]:
    lon, lat, h = normalized[..., 0], normalized[..., 1], normalized[..., 2]
    ll, pp, hh = lon * lon, lat * lat, h * h
    return [
        jnp.ones_like(lon), lon, lat, h, lon * lat, lon * h, lat * h, ll, pp, hh,
        lat * lon * h, ll * lon, lon * pp, lon * hh, ll * lat, pp * lat, lat * hh, ll * h,
        pp * h, hh * h,
    ]  # fmt: skip


def monomials(normalized: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 20"]:
    """The 20 cubic monomials of normalised ``(L, P, H)`` in RPC00B order."""
    return jnp.stack(_monomial_list(jnp.asarray(normalized, dtype=float)), axis=-1)


class RPC(AbstractSensorModel):
    """Rational polynomial camera model (80 coefficients + 10 offsets/scales).

    Fields:
        num: ``(2, 20)`` numerator coefficients, row 0 sample (x), row 1 line (y), RPC00B order.
        den: ``(2, 20)`` denominator coefficients, same layout.
        ground_offset / ground_scale: ``(3,)`` for ``(lon_deg, lat_deg, h_m)``.
        image_offset / image_scale: ``(2,)`` for ``(x, y) = (samp, line)`` in pixels.
    """

    num: Float[Array, "2 20"]
    den: Float[Array, "2 20"]
    ground_offset: Float[Array, "3"]
    ground_scale: Float[Array, "3"]
    image_offset: Float[Array, "2"]
    image_scale: Float[Array, "2"]

    def __init__(
        self,
        num: Float[ArrayLike, "2 20"],
        den: Float[ArrayLike, "2 20"],
        ground_offset: Float[ArrayLike, "3"],
        ground_scale: Float[ArrayLike, "3"],
        image_offset: Float[ArrayLike, "2"],
        image_scale: Float[ArrayLike, "2"],
        order: TermOrder = "RPC00B",
    ):
        self.num = device_array(to_rpc00b(num, order), float)
        self.den = device_array(to_rpc00b(den, order), float)
        self.ground_offset = device_array(ground_offset, float)
        self.ground_scale = device_array(ground_scale, float)
        self.image_offset = device_array(image_offset, float)
        self.image_scale = device_array(image_scale, float)

    def __check_init__(self):
        for name, shape in (
            ("num", (2, 20)),
            ("den", (2, 20)),
            ("ground_offset", (3,)),
            ("ground_scale", (3,)),
            ("image_offset", (2,)),
            ("image_scale", (2,)),
        ):
            got = getattr(self, name).shape
            if got[-len(shape) :] != shape:
                raise ValueError(f"RPC.{name} must have shape (..., {shape}), got {got}")

    @classmethod
    def from_vendor(
        cls,
        *,
        line_num: ArrayLike,
        line_den: ArrayLike,
        samp_num: ArrayLike,
        samp_den: ArrayLike,
        lon_off: float,
        lon_scale: float,
        lat_off: float,
        lat_scale: float,
        height_off: float,
        height_scale: float,
        line_off: float,
        line_scale: float,
        samp_off: float,
        samp_scale: float,
        order: TermOrder = "RPC00B",
    ) -> RPC:
        """Build from the 80 coefficients and 10 offsets/scales under their vendor names."""
        return cls(
            num=np.stack([np.asarray(samp_num, float), np.asarray(line_num, float)]),
            den=np.stack([np.asarray(samp_den, float), np.asarray(line_den, float)]),
            ground_offset=[lon_off, lat_off, height_off],
            ground_scale=[lon_scale, lat_scale, height_scale],
            image_offset=[samp_off, line_off],
            image_scale=[samp_scale, line_scale],
            order=order,
        )

    def to_vendor(self, order: TermOrder = "RPC00B") -> dict[str, np.ndarray | float]:
        """The inverse of :meth:`from_vendor`: vendor names -> numpy values."""
        num, den = np.asarray(self.num), np.asarray(self.den)
        go, gs = np.asarray(self.ground_offset), np.asarray(self.ground_scale)
        io_, is_ = np.asarray(self.image_offset), np.asarray(self.image_scale)
        return {
            "line_num": from_rpc00b(num[1], order),
            "line_den": from_rpc00b(den[1], order),
            "samp_num": from_rpc00b(num[0], order),
            "samp_den": from_rpc00b(den[0], order),
            "lon_off": float(go[0]),
            "lon_scale": float(gs[0]),
            "lat_off": float(go[1]),
            "lat_scale": float(gs[1]),
            "height_off": float(go[2]),
            "height_scale": float(gs[2]),
            "line_off": float(io_[1]),
            "line_scale": float(is_[1]),
            "samp_off": float(io_[0]),
            "samp_scale": float(is_[0]),
        }

    def normalize_ground(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """``(lon_deg, lat_deg, h_m)`` -> normalised ``(L, P, H)``.

        ``lon - lon_off`` is taken into (-180, 180] degrees first, so that a longitude written
        360 degrees apart (an image across the antimeridian, lon_off near +-180) is the same
        point, as in GDAL's RPC transformer.
        """
        ground = jnp.asarray(ground, dtype=float)
        lon, lon_off = ground[..., 0], self.ground_offset[..., 0]
        # the whole turns come off the longitude itself (exact near +-180 deg), not off the
        # difference: lon and lon +- 360 then give bit-identical normalised values
        lon = lon - 360.0 * jnp.ceil((lon - lon_off - 180.0) / 360.0)
        ground = jnp.concatenate([lon[..., None], ground[..., 1:]], axis=-1)
        return (ground - self.ground_offset) / self.ground_scale

    def project(
        self, ground: Float[ArrayLike, "*batch 3"]
    ) -> Float[Array | np.ndarray, "*batch 2"]:
        """Ground ``(lon_deg, lat_deg, h_m)`` -> image ``(x, y)`` px (RPC00B rational functions)."""
        if is_concrete(self, ground):  # a compiled kernel; numpy in -> numpy out
            return project_concrete(self, ground)
        ground = jnp.asarray(ground, dtype=float)
        if ground.shape[-1:] != (3,):
            raise ValueError(
                f"ground coordinates must have a last axis of size 3, got {ground.shape}"
            )
        return project_stacked(self, ground[..., 0], ground[..., 1], ground[..., 2])

    def localize(
        self,
        image: Float[ArrayLike, "*ibatch 2"],
        h: Float[ArrayLike, "*hbatch"],
        guess: Float[ArrayLike, "*gbatch 2"] | None = None,
    ) -> Float[Array | np.ndarray, "... 3"]:
        """See :meth:`AbstractSensorModel.localize`; concrete calls without ``guess`` run a
        compiled kernel (numpy in -> numpy out). Every call runs the same iteration over whole
        arrays (Newton, then chord steps; :func:`~._rpc_eval.localize_lph`): under ``jit``,
        ``vmap`` or ``grad`` the same values and NaN flags as the numpy call, with the
        derivatives of the implicit function theorem."""
        if guess is None and is_concrete(self, image, h):
            return localize_concrete(self, image, h)
        return localize_traced(self, image, h, guess)

    def reference_ground(self) -> Float[Array, "3"]:
        return jnp.asarray(self.ground_offset)

    def adjustable_filter(self) -> PyTree[bool]:
        """Nothing: a bare RPC is adjusted through a :class:`~jaxgeo.models.Biased` wrapper."""
        return nothing(self)

    def required_gcps(self, dynamic: PyTree) -> None:
        return None

    def exact_rpc(self) -> RPC:
        return self

    def base_rpc(self) -> RPC:
        return self

    def in_domain(
        self, ground: Float[ArrayLike, "*batch 3"], margin: float = 0.0
    ) -> Bool[Array, "*batch"]:
        """True where the point lies in the RPC's validity cube (``|normalised| <= 1 + margin``).

        Outside it the RPC still evaluates (as GDAL does) but the vendor's fit says nothing
        about its accuracy there. NaN points are outside.
        """
        n = self.normalize_ground(ground)
        return jnp.all(jnp.abs(n) <= 1.0 + margin, axis=-1)

    def image_in_domain(
        self, image: Float[ArrayLike, "*batch 2"], margin: float = 0.0
    ) -> Bool[Array, "*batch"]:
        """True where ``(x, y)`` lies inside the RPC's image normalisation range."""
        n = (jnp.asarray(image, dtype=float) - self.image_offset) / self.image_scale
        return jnp.all(jnp.abs(n) <= 1.0 + margin, axis=-1)

    def validity_cube(self) -> Float[Array, "2 3"]:
        """``[[lon_min, lat_min, h_min], [lon_max, lat_max, h_max]]`` of the validity cube."""
        return jnp.stack(
            [self.ground_offset - self.ground_scale, self.ground_offset + self.ground_scale]
        )


def check_rpc(rpc: RPC, source: str = "RPC") -> RPC:
    """Raise a ``ValueError`` naming ``source`` on a non-finite value or a zero scale."""
    for name in ("num", "den", "ground_offset", "ground_scale", "image_offset", "image_scale"):
        value = np.asarray(getattr(rpc, name))
        if not np.all(np.isfinite(value)):
            raise ValueError(f"{source}: RPC field {name} holds a non-finite value")
    for name in ("ground_scale", "image_scale"):
        if np.any(np.asarray(getattr(rpc, name)) == 0.0):
            raise ValueError(f"{source}: RPC field {name} holds a zero scale")
    den = np.asarray(rpc.den)
    for i, name in enumerate(("samp_den (SAMP_DEN_COEFF)", "line_den (LINE_DEN_COEFF)")):
        if np.all(den[..., i, :] == 0.0):
            raise ValueError(
                f"{source}: RPC denominator {name} is all zero (the model divides by zero)"
            )
    return rpc
