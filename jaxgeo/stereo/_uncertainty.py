"""The height sigma of DSM points and cells: matching and orientation, propagated by autodiff.

**Points.** A dense match is a left pixel (fixed) and a right pixel whose position along the
epipolar line carries the matching error, of standard deviation ``sigma_d`` (px, from the
correlation peak: :func:`~jaxgeo.stereo.refine_disparity_sigma`). The point's east/north/up
sensitivity to the image coordinates is that of the least-squares intersection at its
solution (implicit function theorem): ``G = (J^T J)^{-1} J^T`` with ``J`` ``(2N, 3)`` the
models' projection Jacobians in px per metre, by ``jax.jacfwd`` (:func:`intersection_jacobian`).
Then

- matching: ``sigma_match = |G_up,right . t| sigma_d``, ``t`` the right sensor displacement of
  one epipolar pixel along the line (from the rectification grids);
- orientation: ``sigma_orient**2 = G_up C G_up^T`` with ``C`` the ``(2N, 2N)`` covariance
  (px^2) of the images' remaining shifts: an adjustment's posterior, from its result
  (:func:`adjustment_covariance`) or its ``adjusted_models.json``
  (:func:`orientation_covariances`: the joint covariance ``jaxgeo adjust`` writes; a file
  with per-image sigmas only overstates the sigma where the adjustment correlates the
  images). Models that were not adjusted carry their vendor's pointing error, which no
  matching sees: a DSM file (:func:`~jaxgeo.stereo.make_dsm`) then takes the a priori
  orientation error (:func:`vendor_orientation`): where an image's RPC states its accuracy
  (RPC00B ``ERR_BIAS``/``ERR_RAND``, m per horizontal axis: :class:`jaxgeo.io.RPCAccuracy`),
  that error mapped into its pixels by the model's ground-to-image Jacobian, else the stated
  default :data:`A_PRIORI_SHIFT_PX` per axis (:func:`a_priori_orientation`); independent
  images. The band's ``covers`` tag and the report say which (:func:`sigma_covers`). The
  posterior of an adjustment (:func:`adjusted_orientation`) is bounded by the same a priori
  in every direction (:func:`bounded_by_a_priori`): what the ties leave open (the relative
  along-track shift of a ties-only block, a height offset to them) stays at the given models'
  values, whose error is the a priori one, not the adjustment's loose prior that held it.
  A zero matrix states exact models (simulations): the matching's sigma alone.

**Cells** (:func:`cell_sigma`). A cell's height is the median of its ``n`` points. The matching
errors of neighbouring points are not independent (their correlation windows overlap by most
of their pixels), so they do not average down over the cell: the cell takes their RMS. The
cell's points also differ from one another (a slope inside the cell, an edge, a false match):
their ``spread`` enters as the standard error of a median, ``sqrt(pi / (2 n)) spread``. The
height is that of the cell's centre, the points lie anywhere in the cell: on a slope ``s`` of
the DSM that adds ``s res / sqrt(12)`` per point (a uniform position over a cell of ``res``),
also over ``n``. The
orientation error is common to every cell (a shift of the whole DSM): it never averages down
and is added in quadrature:
``sigma_cell**2 = rms(sigma_match)**2 + ((pi / 2) spread**2 + s**2 res**2 / 12) / n
+ rms(sigma_orient)**2``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import JaxgeoError
from ..geodesy import metres_per_unit
from ..lsq.internal import inv3_spd
from ..models import AbstractSensorModel

CHUNK = 65536
FALLBACK_CHUNK = 16384
SIGMA_BLOCK = 16384
"""Points per block of :func:`point_height_sigmas`' products (temporaries that stay in cache)."""
"""Points per call of :func:`point_height_sigmas`' per-point Jacobians beside interpolated ones
(NaN-padded: one compiled shape whatever their number, the triangulation lattice's)."""


@dataclasses.dataclass(frozen=True)
class OrientationCovariance:
    """A ``(2N, 2N)`` covariance (px^2) of the models' image shifts with what it holds, in
    words (``covers``: the DSM band's ``covers`` tag, :func:`sigma_covers`): the a priori of
    :func:`vendor_orientation`, the bounded posterior of :func:`adjusted_orientation`."""

    matrix: np.ndarray
    covers: str


Orientation = np.ndarray | OrientationCovariance | Sequence[np.ndarray | None] | None
"""The covariance (px^2) of the models' remaining image shifts ``(x_1, y_1, ..., x_N, y_N)``:
one ``(2N, 2N)`` matrix (with the correlations between images: :func:`adjustment_covariance`,
:func:`orientation_covariances`), or one with its description (:class:`OrientationCovariance`),
or per model a ``2 x 2`` matrix or ``None`` (independent images), or ``None``: for a pair's
points and :func:`~jaxgeo.stereo.dsm_from_images` no orientation term (the matching alone);
for :func:`~jaxgeo.stereo.make_dsm` (``jaxgeo dsm``) models that were not adjusted, with the
a priori :func:`vendor_orientation`."""


def joint_covariance(orientation: Orientation, n_models: int) -> np.ndarray:
    """The ``(2N, 2N)`` matrix of an :data:`Orientation` (zeros for ``None``)."""
    out = np.zeros((2 * n_models, 2 * n_models))
    if orientation is None:
        return out
    if isinstance(orientation, OrientationCovariance):
        orientation = np.asarray(orientation.matrix, float)
    if isinstance(orientation, np.ndarray) and orientation.ndim == 2:
        if orientation.shape != out.shape:
            raise ValueError(
                f"orientation covariance of shape {orientation.shape} for {n_models} images "
                f"(expected {out.shape})"
            )
        return np.asarray(orientation, float)
    if len(orientation) != n_models:
        raise ValueError(f"{len(orientation)} orientation covariances for {n_models} images")
    for i, cov in enumerate(orientation):
        if cov is not None:
            out[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = np.asarray(cov, float)
    return out


A_PRIORI_SHIFT_PX = 0.7
"""A priori sigma (px, per image and axis, independent between images) of the image shift a
model that was not adjusted leaves, for the DSM's ``height_sigma``: the relative pointing of
the images of one pass of a current agile satellite. The s2p Pleiades triplet's relative
orientation moves its biases by 0.2-0.6 px; on simulated Pleiades-like scenes (vendor RPCs:
1-3 px of common pointing error, 0.5 px of mounting per image, 0.5 m of ephemeris, 1.5 px of
jitter) the DSM's height offset over 8 seeds had an RMS of 1.4 m, 0.93 px of relative shift
(0.66 px per image); measured on 6 other seeds in issue 53's closing note. Not the absolute
error (several metres CE90): a shift common to the images moves the DSM in plan, not in
height. Other sensors (Cartosat-1 fore/aft: tens of px) need their adjustment
(``--orientation``)."""


def a_priori_orientation(n_models: int, shift_px: float = A_PRIORI_SHIFT_PX) -> np.ndarray:
    """The ``(2N, 2N)`` :data:`Orientation` of models that were not adjusted: ``shift_px**2``
    on the diagonal (px^2), images independent."""
    return np.eye(2 * int(n_models)) * float(shift_px) ** 2


_NOT_ADJUSTED = "matching and the models' a priori orientation error (not adjusted: "
_REPLACED = (
    "independent images; the posterior of jaxgeo adjust replaces it: --orientation "
    "adjusted_models.json)"
)


def _pixels_per_metre(model: AbstractSensorModel) -> np.ndarray:
    """``(2, 2)``: image ``(x, y)`` px per metre east and north at the model's reference ground
    point (its ground sample distance along each axis, with the image's rotation)."""
    g = jnp.asarray(model.reference_ground(), dtype=float)
    jac = np.asarray(jax.jacfwd(model.project)(g)) / np.asarray(metres_per_unit(g))
    return jac[:, :2]


def vendor_orientation(
    models: Sequence[AbstractSensorModel],
    accuracies: Sequence[object | None],
    names: Sequence[str],
) -> OrientationCovariance:
    """The a priori :class:`OrientationCovariance` of models that were not adjusted (images
    independent): per image its vendor's stated accuracy (``accuracies[i]``, a
    :class:`jaxgeo.io.RPCAccuracy` or ``None``), ``ERR_BIAS`` and ``ERR_RAND`` in quadrature
    (m per horizontal axis on the ground: ``s**2 I`` east/north) mapped into its pixels by the
    model's Jacobian ``J`` (px per metre), ``s**2 J J^T``; where it is unknown, the stated
    default :data:`A_PRIORI_SHIFT_PX` per axis. ``covers`` names each image's source and its
    sigma in px (``"left: vendor ERR_BIAS 3.31 m, ERR_RAND 0.5 m = 6.7 x 6.6 px (x, y)"``,
    ``"right: stated default 0.7 px"``). ``ERR_BIAS`` is the image's absolute pointing error:
    images of one pass share much of it, which moves the DSM in plan rather than in height,
    so for them the sigma is an upper bound (:func:`adjusted_orientation` gives the
    posterior)."""
    n = len(models)
    cov = a_priori_orientation(n)
    parts = []
    for i, (model, accuracy, name) in enumerate(zip(models, accuracies, names, strict=True)):
        total = getattr(accuracy, "horizontal_m", None)
        if total is None:
            parts.append(f"{name}: stated default {A_PRIORI_SHIFT_PX:g} px")
            continue
        jac = _pixels_per_metre(model)
        block = total**2 * (jac @ jac.T)
        cov[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = block
        sx, sy = np.sqrt(np.diag(block))
        parts.append(f"{name}: {accuracy.describe()} = {sx:.2g} x {sy:.2g} px (x, y)")
    covers = _NOT_ADJUSTED + "; ".join(parts) + " per image and axis; " + _REPLACED
    return OrientationCovariance(cov, covers)


def bounded_by_a_priori(posterior: np.ndarray, a_priori: np.ndarray) -> np.ndarray:
    """``posterior`` (``(2N, 2N)`` px^2) with no direction more uncertain than ``a_priori``
    (positive definite): in the metric of ``a_priori`` (``W = A^{-1/2}``), the eigenvalues of
    ``W P W`` above 1 are set to 1. A direction the adjustment left open (its estimate stayed
    at the given models' values, held only by its prior: ``jaxgeo adjust``'s relative
    orientation holds the shifts by 10 px) has the given models' error, the a priori one;
    where the adjustment determined a direction, its posterior stays."""
    lam, v, root = _in_a_priori_metric(posterior, a_priori)
    return root @ ((v * np.clip(lam, 0.0, 1.0)) @ v.T) @ root


def _in_a_priori_metric(posterior, a_priori):
    """The eigenvalues and eigenvectors of ``W P W`` (``W = A^{-1/2}``) and ``A^{1/2}``."""
    vals, vecs = np.linalg.eigh(np.asarray(a_priori, float))
    white = (vecs / np.sqrt(vals)) @ vecs.T
    lam, v = np.linalg.eigh(white @ np.asarray(posterior, float) @ white)
    return lam, v, (vecs * np.sqrt(vals)) @ vecs.T


def resolved_orientation(orientation: Orientation, n_models: int) -> np.ndarray:
    """The ``(2N, 2N)`` covariance a DSM uses: ``orientation``'s (:func:`joint_covariance`),
    or :func:`a_priori_orientation` when it is ``None`` (models not adjusted)."""
    if orientation is None:
        return a_priori_orientation(n_models)
    return joint_covariance(orientation, n_models)


def sigma_covers(orientation: Orientation, n_models: int) -> str:
    """What a DSM's ``height_sigma`` covers with ``orientation`` (before
    :func:`resolved_orientation`), in words: the band's ``covers`` tag and the report's."""
    if orientation is None:
        return (
            _NOT_ADJUSTED
            + f"stated default {A_PRIORI_SHIFT_PX:g} px per image and axis; "
            + _REPLACED
        )
    if isinstance(orientation, OrientationCovariance):
        return orientation.covers
    if not np.any(joint_covariance(orientation, n_models)):
        return "matching only (orientation covariance zero: the models given as exact)"
    return "matching and orientation (the given covariance of the models' image shifts)"


def pair_orientation(orientation: Orientation, n_models: int, i: int, j: int) -> np.ndarray:
    """The ``(4, 4)`` block of images ``i`` and ``j`` of an :data:`Orientation`."""
    idx = np.array([2 * i, 2 * i + 1, 2 * j, 2 * j + 1])
    return joint_covariance(orientation, n_models)[np.ix_(idx, idx)]


def adjustment_covariance(result, images: Sequence[str]) -> np.ndarray:
    """The ``(2N, 2N)`` posterior covariance (px^2) of the bias shifts of ``images`` (names in
    the adjustment) from a :class:`jaxgeo.bundle.AdjustResult`, with the correlations between
    images (as ``adjusted_models.json`` holds it). :class:`OrientationError` when an
    image has no adjusted shift."""
    names = list(result.param_names)
    idx = []
    for image in images:
        for end in SHIFT_PARAMETERS:
            key = f"{image}.{end}"
            if key not in names:
                raise OrientationError(f"adjustment: no adjusted {key} (a bias shift)")
            idx.append(names.index(key))
    from scipy import sparse

    cov = result.param_cov
    if sparse.issparse(cov):  # a banded covariance (a strip)
        return np.asarray(cov[idx][:, idx].toarray(), float)
    return np.asarray(cov, float)[np.ix_(idx, idx)]


class OrientationError(JaxgeoError, ValueError):
    """An orientation file (``adjusted_models.json``) jaxgeo cannot use for the height sigma
    (the message names the file and the image)."""


@eqx.filter_jit
def _jacobian_flat(models, ground):
    def one(g):
        mpu = metres_per_unit(g)
        jac = jnp.concatenate([jax.jacfwd(m.project)(g) / mpu for m in models])  # (2N, 3)
        # closed-form 3x3 inverse: no LAPACK call per point under vmap
        return (inv3_spd(jac.T @ jac) @ jac.T).reshape(3, len(models), 2)

    ok = jnp.all(jnp.isfinite(ground), axis=-1)
    safe = jnp.where(ok[:, None], ground, jnp.stack([m.reference_ground() for m in models])[0])
    out = jax.vmap(one)(safe)
    return jnp.where(ok[:, None, None, None], out, jnp.nan)


def intersection_jacobian(
    models: Sequence[AbstractSensorModel], ground: np.ndarray, chunk: int | None = None
) -> np.ndarray:
    """``(n, 3, N, 2)``: the derivative of the least-squares intersection's east/north/up
    (m) with respect to each image's ``(x, y)`` (px), at the ground points ``(n, 3)``
    ``(lon_deg, lat_deg, h_m)`` (NaN rows give NaN). Computed in chunks of one size (one
    compilation): ``chunk`` points (NaN-padded), or ``min(n,`` :data:`CHUNK` ``)`` when
    ``None``."""
    ground = np.asarray(ground, dtype=float).reshape(-1, 3)
    models = tuple(models)
    n = ground.shape[0]
    out = np.full((n, 3, len(models), 2), np.nan)
    size = min(CHUNK, max(n, 1)) if chunk is None else int(chunk)
    for s in range(0, n, size):
        part = ground[s : s + size]
        k = part.shape[0]
        if k < size:
            part = np.concatenate([part, np.full((size - k, 3), np.nan)])
        out[s : s + k] = np.asarray(_jacobian_flat(models, jnp.asarray(part)))[:k]
    return out


def point_height_sigmas(
    models: Sequence[AbstractSensorModel],
    ground: np.ndarray,
    direction_px: np.ndarray,
    sigma_d_px: np.ndarray,
    orientation: Orientation = None,
    up_jacobian: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Height sigmas (m) of dense points of a pair (module docstring): ``(matching,
    orientation)``, each ``(n,)``. ``ground`` ``(n, 3)`` the points, ``direction_px`` ``(n, 2)``
    the second image's sensor displacement per epipolar pixel of disparity, ``sigma_d_px``
    ``(n,)`` the disparity sigmas, ``orientation`` the models' shift covariance
    (:data:`Orientation`). ``up_jacobian`` ``(n, N, 2)``: the up row of
    :func:`intersection_jacobian` where already known (interpolated between the triangulation
    lattice's nodes: :func:`~jaxgeo.stereo._triangulation.triangulate_disparities`); its NaN
    rows, or all rows when ``None``, are computed here point by point."""
    ground = np.asarray(ground, dtype=float).reshape(-1, 3)
    n = ground.shape[0]
    finite = np.all(np.isfinite(ground), axis=1)
    if up_jacobian is None:
        g = intersection_jacobian(models, ground)[:, 2]  # (n, N, 2): d up / d xy
        todo = np.zeros(n, bool)
    else:  # read as given (no copy of a million rows); the rows it lacks computed below
        g = np.asarray(up_jacobian).reshape(n, len(models), 2)  # float32 promoted per block
        todo = ~np.all(np.isfinite(g), axis=(1, 2)) & finite
    direction_px = np.asarray(direction_px, dtype=float).reshape(n, 2)
    sigma_d_px = np.asarray(sigma_d_px).reshape(n)  # float32 promoted per block
    cov = joint_covariance(orientation, len(models))
    match, orient = np.empty(n), np.empty(n)

    def fill(rows, g):
        flat = g.reshape(g.shape[0], -1)
        match[rows] = np.abs(np.einsum("nc,nc->n", g[:, 1], direction_px[rows])) * sigma_d_px[rows]
        orient[rows] = np.sqrt(np.maximum(np.einsum("na,na->n", flat @ cov, flat), 0.0))

    for s in range(0, n, SIGMA_BLOCK):  # temporaries in cache, not 1e6 x 4
        fill(slice(s, s + SIGMA_BLOCK), g[s : s + SIGMA_BLOCK])
    if todo.any():
        rows = np.flatnonzero(todo)
        fill(rows, intersection_jacobian(models, ground[rows], FALLBACK_CHUNK)[:, 2])
    match[~finite] = np.nan  # a dropped point has no sigma
    orient[~np.isfinite(match)] = np.nan
    return match, orient


def cell_sigma(
    match_ms: np.ndarray,
    orient_ms: np.ndarray,
    spread: np.ndarray,
    count: np.ndarray,
    height: np.ndarray,
    res_m: float,
) -> np.ndarray:
    """The cells' height sigma (m, module docstring) from the mean squares of their points'
    matching and orientation sigmas (m^2), their spread (m), their number of points and the
    grid of heights (for the slope; ``res_m`` the cell size)."""
    n = np.maximum(np.asarray(count, float), 1.0)
    spread = np.nan_to_num(np.asarray(spread, float))
    place = _slope2(height, res_m) * res_m**2 / 12.0
    return np.sqrt(match_ms + (0.5 * np.pi * spread**2 + place) / n + orient_ms)


def _slope2(height, res_m):
    """Squared slope of a height grid (central differences; 0 where a neighbour is NaN: unknown
    at the edges of the data, and along an axis of one cell)."""
    height = np.asarray(height, float)
    out = np.zeros(height.shape)
    for axis in (0, 1):
        if height.shape[axis] > 1:
            out += np.gradient(height, res_m, axis=axis) ** 2
    return np.nan_to_num(out)


SHIFT_PARAMETERS = ("bias.shift_px[0]", "bias.shift_px[1]")
"""The names (their ends) of an image-space bias' constant terms x, y among the ``sigmas`` of
``jaxgeo adjust``'s ``adjusted_models.json``."""


def _shift_sigmas(sigmas: Mapping[str, float]) -> tuple[float, float] | None:
    """The posterior sigmas (px) of a bias' constant x and y terms among an image's
    ``sigmas``."""
    found = [
        next((float(v) for k, v in sigmas.items() if k.endswith(name)), None)
        for name in SHIFT_PARAMETERS
    ]
    return None if None in found else (found[0], found[1])


def orientation_covariances(
    path: str | os.PathLike, images: Sequence[str | os.PathLike]
) -> np.ndarray:
    """The ``(2N, 2N)`` covariance (px^2, :data:`Orientation`) of the remaining image-space
    shifts of ``images`` after ``jaxgeo adjust``, from the adjustment's
    ``adjusted_models.json`` (``path``); each image found by its name in the adjustment
    (``--image NAME=...``: the file name without directories and suffixes, or with
    ``_adjusted``/``_RPC`` dropped).

    With a top-level ``"covariance": {"parameters": [names], "matrix": [[...]]}`` (names as in
    the images' ``sigmas``, prefixed with the image: ``left.bias.shift_px[0]``), the joint
    posterior covariance of the shifts, correlations between images included. Otherwise the
    posterior sigmas of each image's shift, independent between images: where the adjustment
    correlates them (the same GCPs in both images) that overstates the height sigma (1.35x on
    a simulated pair). The sigmas of drift or affine terms are not used: a constant shift per
    image. :class:`OrientationError` naming the file and image when an image or its sigmas are
    missing."""
    path = pathlib.Path(path)
    try:
        data = json.loads(path.read_text())
        entries = data["images"]
        joint = data.get("covariance")
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as err:
        raise OrientationError(
            f"{path}: not an adjusted_models.json written by jaxgeo adjust ({err})"
        ) from None
    keys, sigmas = [], []
    for image in images:
        name = pathlib.Path(image).name
        stems = [name.split(".")[0], pathlib.Path(image).stem]
        stems += [s.replace("_adjusted", "").replace("_RPC", "") for s in stems]
        key = next((s for s in stems if s in entries), None)
        if key is None:
            raise OrientationError(
                f"{path}: no image named {stems[0]!r} (for {image}); it holds "
                f"{', '.join(sorted(entries))}"
            )
        sig = _shift_sigmas(entries[key].get("sigmas", {}))
        if sig is None or not all(np.isfinite(sig)):
            raise OrientationError(
                f"{path}: image {key!r} has no posterior sigmas of a bias shift (x, y)"
            )
        keys.append(key)
        sigmas.append(np.diag(np.square(sig)))
    if joint is None:
        return joint_covariance(sigmas, len(images))
    try:
        names = list(joint["parameters"])
        matrix = np.asarray(joint["matrix"], float)
        idx = [names.index(f"{k}.{end}") for k in keys for end in SHIFT_PARAMETERS]
        return matrix[np.ix_(idx, idx)]
    except (KeyError, TypeError, ValueError, IndexError) as err:
        raise OrientationError(
            f"{path}: its covariance does not hold the bias shifts of {', '.join(keys)} ({err})"
        ) from None


def adjusted_orientation(
    path: str | os.PathLike,
    images: Sequence[str | os.PathLike],
    a_priori: OrientationCovariance | None = None,
) -> OrientationCovariance:
    """The orientation a DSM of ``images`` takes from ``jaxgeo adjust``'s
    ``adjusted_models.json`` (``path``): the posterior of :func:`orientation_covariances`,
    bounded in every direction by the a priori (:func:`bounded_by_a_priori`; ``a_priori``:
    :func:`vendor_orientation` of the given models, default the stated
    :data:`A_PRIORI_SHIFT_PX` per image and axis). ``covers`` says so, with how many of the
    ``2N`` directions the adjustment left open (bounded). :class:`OrientationError` as
    :func:`orientation_covariances`."""
    posterior = orientation_covariances(path, images)
    n = len(images)
    prior = a_priori_orientation(n) if a_priori is None else joint_covariance(a_priori, n)
    bounded = bounded_by_a_priori(posterior, prior)
    n_open = int(np.sum(_in_a_priori_metric(posterior, prior)[0] > 1.0))
    if a_priori is None:
        source = f"the stated default {A_PRIORI_SHIFT_PX:g} px per image and axis"
    else:
        source = a_priori.covers.removeprefix(_NOT_ADJUSTED).split("; independent")[0]
    covers = (
        f"matching and orientation (the posterior of jaxgeo adjust, {pathlib.Path(path).name}; "
        f"{n_open} of its {2 * n} shift directions left open by the adjustment (e.g. the "
        "relative along-track shift without GCPs) take the models' a priori error instead of "
        f"the adjustment's prior: {source})"
    )
    return OrientationCovariance(bounded, covers)


def sigma_calibration(
    height: np.ndarray, height_sigma: np.ndarray, truth: np.ndarray
) -> dict[str, float]:
    """How well ``height_sigma`` describes the errors of ``height`` against ``truth`` (grids of
    one shape, m; NaN: none) over the cells where all three are finite: ``n_cells``,
    ``within_1_sigma`` and ``within_2_sigma`` (shares of cells with ``|height - truth|`` at most
    one / two sigmas; a Gaussian's: 0.683, 0.954), ``median_ratio`` (median of
    ``|height - truth| / sigma``; a Gaussian's: 0.674), ``rmse_m``, ``median_sigma_m``."""
    err = np.asarray(height, float) - np.asarray(truth, float)
    sigma = np.asarray(height_sigma, float)
    ok = np.isfinite(err) & np.isfinite(sigma) & (sigma > 0)
    ratio = np.abs(err[ok]) / sigma[ok]
    if not ok.any():
        return dict(n_cells=0)
    return dict(
        n_cells=int(ok.sum()),
        within_1_sigma=float(np.mean(ratio <= 1.0)),
        within_2_sigma=float(np.mean(ratio <= 2.0)),
        median_ratio=float(np.median(ratio)),
        rmse_m=float(np.sqrt(np.mean(err[ok] ** 2))),
        median_sigma_m=float(np.median(sigma[ok])),
    )
