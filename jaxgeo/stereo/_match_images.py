"""Tie points of several images: every pair matched (:func:`~jaxgeo.stereo.tie_points`), the
pairs' ties joined into multi-image points (:func:`~jaxgeo.stereo.join_ties`), the observations
that :func:`jaxgeo.adjust` reads.

``match_images([open_image(p) for p in paths], MatchSettings())`` is what ``jaxgeo match``
does: SIFT keypoints of each image once (of the first image over ``settings.roi``), every pair
``(i, j)``, ``i < j``, matched and verified, a :class:`~jaxgeo.stereo.TieWarning` naming a pair
with fewer than ``settings.few_ties`` ties, then the ties that share a keypoint joined into one
point seen in all those images (which ties the pairs' heights together in an adjustment).
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .._runtime.progress import Progress
from ..errors import JaxgeoWarning
from ..io import Observations, SensorImage, write_observations
from ._join import join_ties
from ._match_settings import MatchSettings, TieError, TieWarning
from ._matching import sift_features_raster
from ._ties import TieReport, _check_roi, tie_points


class NoTiesError(TieError):
    """No tie point survived the checks in any pair; ``reports`` says, per pair, what was
    found and rejected (:meth:`TieReport.summary`)."""

    def __init__(self, message: str, reports: tuple[TieReport, ...]):
        super().__init__(message)
        self.reports = reports


@dataclass(frozen=True)
class TieResult:
    """What :func:`match_images` found: the ``observations`` (ids ``tie0``, ``tie1``... zero
    padded, image names, raster px, ``sigma_px``), the ``pairs``' reports (:class:`TieReport`
    with the pair's ``images``, in matching order), ``n_points`` multi-image points,
    ``points_by_views`` ``{images seen in: points}`` and ``n_conflicting_dropped`` groups of ties
    dropped because they reach two positions of one image."""

    observations: Observations
    pairs: tuple[TieReport, ...]
    n_points: int
    points_by_views: dict[int, int]
    n_conflicting_dropped: int

    def as_dict(self) -> dict:
        """Plain JSON-able values (``jaxgeo match --json`` prints them, with ``out``)."""
        return {
            "n_points": self.n_points,
            "n_observations": len(self.observations),
            "points_by_views": dict(self.points_by_views),
            "n_conflicting_dropped": self.n_conflicting_dropped,
            "pairs": [r.as_dict() for r in self.pairs],
        }

    def describe(self) -> str:
        """One phrase: the points, by the number of images they are seen in, and the
        observations."""
        seen = ", ".join(f"{n} in {v} images" for v, n in self.points_by_views.items())
        dropped = (
            f"; {self.n_conflicting_dropped} groups of ties reaching two points of one image "
            "dropped"
            if self.n_conflicting_dropped
            else ""
        )
        return (
            f"{self.n_points} tie points ({seen}; ties sharing a keypoint joined{dropped}), "
            f"{len(self.observations)} observations"
        )

    def write(self, path: str | os.PathLike, overwrite: bool = False) -> pathlib.Path:
        """The observations CSV (``id,image,x,y,sigma_px``, :func:`jaxgeo.io.write_observations`)
        written atomically; an existing file is replaced only with ``overwrite``."""
        return write_observations(self.observations, path, overwrite=overwrite)


def _check_images(images: Sequence[SensorImage], settings: MatchSettings) -> None:
    if len(images) < 2:
        raise TieError(f"match_images: give at least two images, got {len(images)}")
    names = [im.name for im in images]
    if len(set(names)) != len(names):
        raise TieError(f"match_images: image names must differ (they name the images): {names}")
    for im in images:
        if im.path is None or im.size is None:
            raise TieError(f"match_images: image {im.name} has no raster to match")
    _check_roi(settings.roi, images[0].size, images[0].path)


def _pair_ties(a: SensorImage, b: SensorImage, settings, dem, features):
    """:func:`tie_points` of one pair; jaxgeo's warnings of it issued again naming the pair."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ties = tie_points(a.model, b.model, a.path, b.path, settings, dem=dem,
                          features1=features[0], features2=features[1])  # fmt: skip
    for w in caught:
        if issubclass(w.category, JaxgeoWarning):
            warnings.warn(f"{a.name} - {b.name}: {w.message}", w.category, stacklevel=3)
        else:  # another library's notice: back to Python's filters as it was
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return ties


def match_images(
    images: Sequence[SensorImage],
    settings: MatchSettings | None = None,
    *,
    dem=None,
    progress: bool | Callable[[str], None] | None = None,
) -> TieResult:
    """Verified tie points of every pair of ``images``, joined into multi-image points (module
    docstring).

    ``images``: two or more :class:`jaxgeo.io.SensorImage` (:func:`jaxgeo.io.open_image`: a
    raster and its model in the raster's pixels), named differently (their ``name`` names them
    in the observations). ``settings``: :class:`MatchSettings` (``roi`` applies to the first
    image, in its pairs); ``dem``: a :class:`jaxgeo.io.DEM` whose heights over the footprint
    give the height range when ``settings.height_range_m`` is ``None``. ``progress``: ``True``,
    the stages (each image's SIFT, each pair) counted on stderr with their rate and ETA
    (:class:`~jaxgeo._runtime.progress.Progress`); a callable, called with a line per stage;
    ``None`` or ``False``: silent.

    Warnings: a :class:`TieWarning` for a pair with fewer than ``settings.few_ties`` ties, and
    those of :func:`tie_points`, each naming its pair (``"a - b: ..."``). Raises
    :class:`TieError` for images or an ROI that cannot be matched, :class:`NoTiesError` (with
    the pairs' reports) when no tie survives in any pair.
    """
    settings = MatchSettings() if settings is None else settings
    _check_images(images, settings)
    n_pairs = len(images) * (len(images) - 1) // 2
    bar = Progress("match", len(images) + n_pairs, "step", enabled=progress is True)
    say = progress if callable(progress) else bar.note
    features = []
    for k, im in enumerate(images):
        say(f"SIFT keypoints of {im.name} ({k + 1}/{len(images)})")
        features.append(sift_features_raster(im.path, settings.roi if k == 0 else None))
        bar.update()
    # the ROI is the first image's: the pairs of the others search their whole images
    others = dataclasses.replace(settings, roi=None)
    found, reports = [], []
    for i in range(len(images)):
        for j in range(i + 1, len(images)):
            a, b = images[i], images[j]
            say(f"matching {a.name} - {b.name}")
            pair = settings if i == 0 else others
            ties = _pair_ties(a, b, pair, dem, (features[i], features[j]))
            if len(ties) < settings.few_ties:
                warnings.warn(
                    f"{a.name} - {b.name}: only {len(ties)} ties (do the images overlap? are the "
                    "models right? a larger epipolar_tol_px for a large relative bias?)",
                    TieWarning,
                    stacklevel=2,
                )
            reports.append(dataclasses.replace(ties.report, images=(a.name, b.name)))
            found.append((i, j, ties.xy1, ties.xy2))
            bar.update()
    bar.close()
    joined = join_ties(found)
    if len(joined.point) == 0:
        raise NoTiesError(
            "no tie point survived the checks in any pair (see the summary)", tuple(reports)
        )
    names = [im.name for im in images]
    width = len(str(len(joined.n_views) - 1))
    obs = Observations(
        tuple(f"tie{k:0{width}d}" for k in joined.point),
        tuple(names[k] for k in joined.image),
        joined.xy,
        np.full(len(joined.point), float(settings.sigma_px)),
    )
    views = {int(v): int(n) for v, n in enumerate(np.bincount(joined.n_views)) if n}
    return TieResult(obs, tuple(reports), len(joined.n_views), views, joined.n_conflicting)
