"""A stereo pair with many tie points: the scale case of ``jaxgeo adjust`` (issue 11).

The two RPCs of the demo scene (:mod:`._demo`, a Cartosat-1 pair) are the given models. The
truth differs from them by an image-space affine bias per image (a small shift in ``fore``, a
small *relative* affine bias in ``aft``). Tie points are spread over the common area on a
smooth terrain and measured in both images (true projection + Gaussian noise); a fraction of
the tie measurements get gross errors (tens of pixels). GCPs are measured in ``fore`` only, so
that ``aft`` is controlled through the ties alone (plus bias priors or tie heights from a
DEM), as in a real pair whose GCPs were measured in one image.

Deterministic for a seed. :func:`tie_pair` returns a :class:`TiePair`; :meth:`TiePair.save`
writes ``fore.txt``, ``aft.txt``, ``ground.csv``, ``observations.csv`` and ``truth.json``.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import shutil

import numpy as np

from ..geodesy import metres_per_unit
from ..io import GroundPoints, Observations, read_rpc, write_ground, write_observations
from ..io.internal import atomic_write_text
from ..models import AffineBias, Biased, localize_points, project_points
from . import _scene as sc
from ._demo import demo_dir

NAMES = ("fore", "aft")
FORE_BIAS = AffineBias((2.5, -3.0), ((0.0, 0.0), (0.0, 0.0)))
"""The true bias of ``fore`` (px): a shift, what its GCPs determine."""
AFT_BIAS = AffineBias((1.2, -0.8), ((3e-5, -2e-5), (1e-5, 4e-5)))
"""The true bias of ``aft``: a small affine bias relative to ``fore`` (px, px/px)."""


@dataclasses.dataclass(frozen=True)
class TiePair:
    """A simulated pair: given RPCs (files), observations, GCPs, and the truth.

    ``gross``: per observation, whether it carries a gross error; ``ground_true``: the true
    ``truth``: JSON-ready description (biases, gross-error indices, the true points).
    """

    rpc_files: dict[str, pathlib.Path]
    observations: Observations
    ground: GroundPoints
    gross: np.ndarray
    truth: dict

    def detectable(self, threshold_px: float = 3.0) -> np.ndarray:
        """Per observation: a gross error whose component across the epipolar direction (the
        image motion of a height change of its point) exceeds ``threshold_px``. Along that
        direction a two-ray tie point's gross error only moves its height: no test sees it."""
        off = np.asarray(self.truth["gross_offset_px"], float).reshape(-1, 2)
        along = np.asarray(self.truth["height_direction"], float).reshape(-1, 2)
        across = np.abs(off[:, 0] * along[:, 1] - off[:, 1] * along[:, 0])
        out = np.zeros(len(self.gross), dtype=bool)
        out[self.gross] = across > threshold_px
        return out

    def save(self, directory: str | os.PathLike) -> dict[str, pathlib.Path]:
        """Write the pair's files into ``directory`` (created); returns them by role."""
        d = pathlib.Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        out = {}
        for name, src in self.rpc_files.items():
            out[name] = pathlib.Path(shutil.copyfile(src, d / src.name))
        out["ground"] = write_ground(self.ground, d / "ground.csv")
        out["observations"] = write_observations(self.observations, d / "observations.csv")
        out["truth"] = atomic_write_text(d / "truth.json", json.dumps(self.truth, indent=1))
        return out


def _rounded(g: np.ndarray) -> np.ndarray:
    """Ground points as written: 1e-10 deg, 0.1 mm."""
    return np.concatenate([np.round(g[:, :2], 10), np.round(g[:, 2:], 4)], axis=1)


def terrain_height(lon, lat, centre, h0: float = 630.0, amplitude: float = 400.0):
    """A smooth terrain (m): two crossing waves of a few kilometres around ``centre``."""
    mpu = metres_per_unit(np.asarray(centre, float), xp=np)
    dx, dy = (np.asarray(lon) - centre[0]) * mpu[0], (np.asarray(lat) - centre[1]) * mpu[1]
    return h0 + amplitude * np.sin(dx / 4e3) * np.cos(dy / 5.5e3) + 0.2 * amplitude * dx / 2e4


@dataclasses.dataclass(frozen=True)
class TiePairSettings:
    """The options of :func:`tie_pair`: ``n_gcps`` GCPs measured in ``fore`` only,
    ``gross_fraction`` of the tie measurements off by ``gross_px`` (min, max) in a random
    direction, image noise ``noise_px`` and a-priori ``sigma_px``, GCP survey noise
    ``gcp_noise_m`` and a-priori ``gcp_sigma_m``, points kept ``margin_px`` inside both
    images. Checked when made (a bad value names the field)."""

    n_gcps: int = 12
    gross_fraction: float = 0.01
    gross_px: tuple[float, float] = (8.0, 60.0)
    noise_px: float = 0.3
    sigma_px: float = 0.5
    gcp_noise_m: float = 0.1
    gcp_sigma_m: float = 0.3
    margin_px: float = 300.0

    def __post_init__(self):
        sc.check_int(self, "n_gcps", 0)
        f = self.gross_fraction
        sc.require(sc.is_real(f) and 0 <= f <= 1, "gross_fraction", "be in [0, 1]", f)
        sc.check_range(self, "gross_px", positive=True)
        sc.check_non_negative(self, "noise_px", "gcp_noise_m", "margin_px")
        sc.check_positive(self, "sigma_px", "gcp_sigma_m")


def tie_pair(
    n_ties: int = 100_000, seed: int = 0, settings: TiePairSettings | None = None
) -> TiePair:
    """Simulate the pair (see the module docstring) with ``settings`` (:class:`TiePairSettings`):
    ``n_ties`` tie points in both images, a fraction of their measurements with gross errors,
    GCPs measured in ``fore`` only. Deterministic in ``seed``."""
    s = TiePairSettings() if settings is None else settings
    n_gcps, gross_fraction, gross_px = s.n_gcps, s.gross_fraction, s.gross_px
    noise_px, sigma_px, margin_px = s.noise_px, s.sigma_px, s.margin_px
    gcp_noise_m, gcp_sigma_m = s.gcp_noise_m, s.gcp_sigma_m
    rng = np.random.default_rng(seed)
    files = {n: demo_dir() / f"{n}.txt" for n in NAMES}
    rpcs = {n: read_rpc(p) for n, p in files.items()}
    truth = {"fore": Biased(rpcs["fore"], FORE_BIAS), "aft": Biased(rpcs["aft"], AFT_BIAS)}
    fore = truth["fore"]
    centre = np.asarray(rpcs["fore"].ground_offset, float)
    n_all = n_ties + n_gcps
    # candidate points in fore on the terrain (two fixed-point passes on the height), kept where
    # both images see them
    size = 2.0 * np.asarray(rpcs["fore"].image_scale, float) + 1.0
    cand = margin_px + (size - 2 * margin_px) * rng.uniform(0.0, 1.0, (2 * n_all, 2))
    h = np.full(len(cand), centre[2])
    for _ in range(3):
        g = localize_points(fore, cand, h)
        h = terrain_height(g[:, 0], g[:, 1], centre)
    g = localize_points(fore, cand, h)
    xy_aft = project_points(truth["aft"], g)
    inside = np.all((xy_aft > margin_px) & (xy_aft < size - margin_px), axis=1)
    keep = np.flatnonzero(inside & np.all(np.isfinite(g), axis=1))[:n_all]
    if len(keep) < n_all:
        raise ValueError(f"could only place {len(keep)} of {n_all} points in both images")
    ground_true = g[keep]
    xy_true = {"fore": cand[keep], "aft": xy_aft[keep]}
    ties, gcps = np.arange(n_ties), np.arange(n_ties, n_all)
    tie_ids = [f"T{i:06d}" for i in range(n_ties)]
    gcp_ids = [f"G{i:03d}" for i in range(n_gcps)]
    # observations: ties in both images, GCPs in fore only
    pids, imgs, xy = [], [], []
    for name in NAMES:
        pids += tie_ids
        imgs += [name] * n_ties
        xy.append(xy_true[name][ties])
    pids += gcp_ids
    imgs += ["fore"] * n_gcps
    xy.append(xy_true["fore"][gcps])
    xy = np.concatenate(xy)
    xy = xy + rng.normal(0.0, noise_px, xy.shape)
    m_ties = 2 * n_ties
    gross = np.zeros(len(xy), dtype=bool)
    bad = rng.choice(m_ties, size=int(round(gross_fraction * m_ties)), replace=False)
    bad = np.sort(bad)
    gross[bad] = True
    angle = rng.uniform(0.0, 2 * np.pi, len(bad))
    length = rng.uniform(*gross_px, len(bad))
    offset = length[:, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    xy[bad] += offset
    # image direction of a height change at each gross error (unit vector)
    point = np.concatenate([ties, ties, gcps])[bad]
    img = np.asarray(imgs)[bad]
    up = ground_true[point] + np.array([0.0, 0.0, 1.0])
    direction = np.zeros((len(bad), 2))
    for name in NAMES:
        sel = img == name
        d = project_points(truth[name], up[sel]) - xy_true[name][point[sel]]
        direction[sel] = d / np.linalg.norm(d, axis=1, keepdims=True)
    obs = Observations(tuple(pids), tuple(imgs), np.round(xy, 4), np.full(len(xy), float(sigma_px)))
    # GCPs surveyed with noise (metres -> degrees at the point)
    enu = rng.normal(0.0, gcp_noise_m, (n_gcps, 3))
    surveyed = ground_true[gcps] + enu / metres_per_unit(ground_true[gcps], xp=np)
    ground = GroundPoints(
        tuple(gcp_ids),
        _rounded(surveyed),
        ("gcp",) * n_gcps,
        np.full((n_gcps, 3), float(gcp_sigma_m)),
    )
    info = {
        "n_ties": n_ties,
        "n_gcps": n_gcps,
        "seed": seed,
        "gross_observations": int(gross.sum()),
        "bias": {
            n: {
                "shift_px": np.asarray(b.shift_px).tolist(),
                "matrix": np.asarray(b.matrix).tolist(),
            }
            for n, b in (("fore", FORE_BIAS), ("aft", AFT_BIAS))
        },
        "gross_index": bad.tolist(),
        "gross_offset_px": np.round(offset, 4).tolist(),
        "height_direction": np.round(direction, 6).tolist(),
        "ground_true": _rounded(ground_true).tolist(),
    }
    return TiePair(files, obs, ground, gross, info)
