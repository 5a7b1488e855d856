"""Level 2 of the full-strip adjustment: the universal lat/lon correction (003_ eq. 12-13).

    dlat = a0 + a1 lat + a2 lon + a3 lat^2 + a4 lon^2 + a5 lat lon
    dlon = b0 + b1 lat + b2 lon + b3 lat^2 + b4 lon^2 + b5 lat lon

with ``(lat, lon)`` the ground coordinates after the level-1 (relative) adjustment, normalised
"as in the RPCs" (offset and scale of the GCPs' extent), and ``(dlat, dlon)`` in degrees the
correction that takes them to the true coordinates. One correction serves the whole strip, so
sub-scenes without GCPs are corrected too.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PyTree

from ..models import AbstractSensorModel
from ..models.internal import nothing
from ._errors import ConfigError, Setting

N_TERMS = {"none": 0, "shift": 1, "affine": 3, "quadratic": 6}
"""Leading terms of eq. 12-13 kept by each degree (the paper uses ``quadratic``; ``none`` is the
identity, for comparison)."""
TERM_NAMES = ("1", "lat", "lon", "lat^2", "lon^2", "lat*lon")
"""The terms of eq. 12-13 in coefficient order (of the normalised lat, lon)."""


def _terms(lat_n, lon_n):
    return jnp.stack(
        [jnp.ones_like(lat_n), lat_n, lon_n, lat_n**2, lon_n**2, lat_n * lon_n], axis=-1
    )


class UniversalCorrection(eqx.Module):
    """The eq. 12-13 correction: ``coeffs`` ``(2, 6)``, row 0 ``a`` (dlat), row 1 ``b`` (dlon).

    ``offset``/``scale`` ``(2,)`` normalise ``(lat_deg, lon_deg)``; degrees throughout.
    """

    coeffs: Float[Array, "2 6"]
    offset: Float[Array, "2"]
    scale: Float[Array, "2"]

    def delta(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        """``(dlon_deg, dlat_deg)`` at ``(lon_deg, lat_deg, h_m)`` (level-1 coordinates)."""
        ground = jnp.asarray(ground, dtype=float)
        lat_n = (ground[..., 1] - self.offset[0]) / self.scale[0]
        lon_n = (ground[..., 0] - self.offset[1]) / self.scale[1]
        t = _terms(lat_n, lon_n)
        dlat = t @ self.coeffs[0]
        dlon = t @ self.coeffs[1]
        return jnp.stack([dlon, dlat], axis=-1)

    def apply(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """Level-1 ground -> corrected (absolute) ground."""
        ground = jnp.asarray(ground, dtype=float)
        return ground.at[..., :2].add(self.delta(ground))

    def invert(
        self, ground: Float[ArrayLike, "*batch 3"], iterations: int = 4
    ) -> Float[Array, "*batch 3"]:
        """Corrected ground -> level-1 ground (fixed point; the correction is tiny and smooth)."""
        ground = jnp.asarray(ground, dtype=float)
        level1 = ground
        for _ in range(iterations):
            level1 = ground.at[..., :2].add(-self.delta(level1))
        return level1


def fit_universal_correction(
    level1: Float[ArrayLike, "n 3"],
    truth: Float[ArrayLike, "n 3"],
    degree: str = "quadratic",
) -> tuple[UniversalCorrection, np.ndarray]:
    """Least-squares fit of eq. 12-13 from GCPs: level-1 ground and true ground, ``(n, 3)``.

    Returns the correction and the residuals ``(n, 2)`` (dlon, dlat) in degrees after the fit.
    Needs at least as many GCPs as terms (6 for ``quadratic``); fewer raise a ``ValueError``.
    """
    if degree not in N_TERMS or degree == "none":
        raise ValueError(f"degree must be one of {list(N_TERMS)[1:]}, got {degree!r}")
    level1 = np.asarray(level1, dtype=float).reshape(-1, 3)
    truth = np.asarray(truth, dtype=float).reshape(-1, 3)
    if not (np.all(np.isfinite(level1)) and np.all(np.isfinite(truth))):
        raise ValueError("universal correction: non-finite GCP coordinates")
    check_design(level1, degree)
    corr = fit_correction(jnp.asarray(level1), jnp.asarray(truth), degree)
    resid = (truth - np.asarray(corr.apply(level1)))[:, :2]
    return corr, resid


def check_design(level1: np.ndarray, degree: str, where: str = "") -> None:
    """Raise a :class:`~._errors.ConfigError` (prefixed with ``where``, e.g. the GCP file) if
    GCPs at ``level1`` (n, 3) cannot determine the correction."""
    level1 = np.asarray(level1, dtype=float).reshape(-1, 3)
    k, n = N_TERMS[degree], len(level1)
    where = where.replace("{", "{{").replace("}", "}}")  # a template: settings named by format
    if n < k:
        raise ConfigError(
            f"{where}the {degree} universal correction needs at least {k} GCPs, got {n} "
            "(use {0} (3) or {1} (1))",
            Setting("level2.degree", "affine"),
            Setting("level2.degree", "shift"),
        )
    latlon = level1[:, [1, 0]]
    offset = latlon.mean(axis=0)
    scale = np.maximum(np.abs(latlon - offset).max(axis=0), 1e-9)
    t = np.asarray(_terms(*((latlon - offset) / scale).T))[:, :k]
    rank = np.linalg.matrix_rank(t, tol=1e-8 * np.abs(t).max())
    if rank < k:
        raise ConfigError(
            f"{where}the {degree} universal correction is not determined by these {n} GCPs "
            f"(design rank {rank} < {k}: GCPs too few or aligned along the strip)"
        )


def _normal_solve(t: Float[Array, "n k"], d: Float[Array, "n 2"]) -> Float[Array, "k 2"]:
    """Least squares by the normal equations with an unrolled Cholesky (``k <= 6``).

    Pure arithmetic, no LAPACK call: many tiny batched SVD/LAPACK kernels inside one compiled
    function were seen to deadlock XLA's CPU thread pool on a 2-core machine. The design is
    normalised (terms in [-1, 1]), so squaring its condition number costs nothing here; a
    1e-12 relative ridge keeps a rank-deficient (cross-validation) fit finite.
    """
    k = t.shape[1]
    a = t.T @ t
    a = a + 1e-12 * (jnp.trace(a) / k + 1e-300) * jnp.eye(k)
    b = t.T @ d
    low = [[None] * k for _ in range(k)]
    for j in range(k):
        diag = a[j, j] - sum((low[j][m] ** 2 for m in range(j)), 0.0)
        low[j][j] = jnp.sqrt(jnp.maximum(diag, 1e-300))
        for i in range(j + 1, k):
            off = a[i, j] - sum((low[i][m] * low[j][m] for m in range(j)), 0.0)
            low[i][j] = off / low[j][j]
    y = [None] * k
    for i in range(k):
        y[i] = (b[i] - sum((low[i][m] * y[m] for m in range(i)), 0.0)) / low[i][i]
    x = [None] * k
    for i in reversed(range(k)):
        x[i] = (y[i] - sum((low[m][i] * x[m] for m in range(i + 1, k)), 0.0)) / low[i][i]
    return jnp.stack(x)


def fit_correction(
    level1: Float[Array, "n 3"],
    truth: Float[Array, "n 3"],
    degree: str = "quadratic",
    weight: Float[Array, " n"] | None = None,
) -> UniversalCorrection:
    """The least-squares fit of eq. 12-13 as a pure jax function (jit, vmap), no checks.

    ``weight`` (n,) >= 0 the GCPs' weights in the normal equations (0 masks a GCP out, e.g. a
    gross error or padding in a batch); see :func:`fit_universal_correction` for the checked
    numpy entry point.
    """
    k = N_TERMS[degree]
    w = jnp.ones(level1.shape[0]) if weight is None else weight
    if k == 0:
        return UniversalCorrection(jnp.zeros((2, 6)), jnp.zeros(2), jnp.ones(2))
    latlon = level1[:, jnp.array([1, 0])]
    on = (w > 0).astype(latlon.dtype)  # the normalisation: the extent of the GCPs used
    offset = jnp.sum(on[:, None] * latlon, axis=0) / jnp.maximum(jnp.sum(on), 1.0)
    scale = jnp.maximum(jnp.max(on[:, None] * jnp.abs(latlon - offset), axis=0), 1e-9)
    root = jnp.sqrt(w)[:, None]  # rows scaled by sqrt(w): weight w in the normal equations
    t = _terms(*((latlon - offset) / scale).T)[:, :k] * root
    d = (truth - level1)[:, jnp.array([1, 0])] * root  # (dlat, dlon)
    sol = _normal_solve(t, d)
    coeffs = jnp.zeros((2, 6)).at[:, :k].set(sol.T)
    return UniversalCorrection(coeffs, offset, scale)


class UniversallyCorrected(AbstractSensorModel):
    """A sensor model followed by the universal correction: ground truth -> image.

    ``project(g) = model.project(correction.invert(g))``: the level-1 model sees the ground point
    where the uncorrected strip puts it.
    """

    model: AbstractSensorModel
    correction: UniversalCorrection

    def project(self, ground: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 2"]:
        return self.model.project(self.correction.invert(ground))

    def localize(self, image, h, guess=None):
        return self.correction.apply(self.model.localize(image, h, guess))

    def reference_ground(self) -> Float[Array, "3"]:
        return self.correction.apply(self.model.reference_ground())

    def adjustable_filter(self) -> PyTree[bool]:
        """The wrapped model's adjustable leaves; the correction stays fixed."""
        return eqx.tree_at(lambda m: m.model, nothing(self), self.model.adjustable_filter())

    def required_gcps(self, dynamic: PyTree) -> tuple[int, str] | None:
        """What the wrapped model needs for its adjusted part."""
        return self.model.required_gcps(dynamic.model)

    def base_rpc(self):
        """The wrapped model's RPC."""
        return self.model.base_rpc()


def cross_validate(
    level1: Float[Array, "n 3"],
    truth: Float[Array, "n 3"],
    groups: Float[Array, "G n"],
    metres_per_unit: Float[Array, "n 3"],
    weight: Float[Array, " n"] | None = None,
) -> Float[Array, " d"]:
    """Leave-one-group-out RMS (m, planimetric) of every degree of :data:`N_TERMS`, in order.

    ``groups`` (G, n) 0/1: the GCPs of each sub-scene with GCPs; each group is predicted by the
    correction fitted to all the others -- how well the correction carries to scenes without
    GCPs, which is what level 2 is for. ``weight`` (n,): the GCPs' weights (0: a gross error,
    neither fitted nor predicted). Pure jax.
    """
    w = jnp.ones(level1.shape[0]) if weight is None else weight
    groups = groups * (w > 0)
    n_left = jnp.maximum(jnp.sum(groups), 1.0)

    def one(degree):
        def left_out(g):
            corr = fit_correction(level1, truth, degree, weight=w * (1.0 - g))
            err = (corr.apply(level1) - truth)[:, :2] * metres_per_unit[:, :2]
            return jnp.sum(g * jnp.sum(err**2, axis=-1))

        return jnp.sqrt(jnp.sum(jax.vmap(left_out)(groups)) / n_left)

    return jnp.stack([one(d) for d in N_TERMS])
