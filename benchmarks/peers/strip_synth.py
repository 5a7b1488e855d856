"""A synthetic strip problem for exercising the peer solvers (:mod:`benchmarks.peers.strip`).

``make_problem(n_scenes, ties_per_pair, seed)`` copies one real Pleiades RPC
(``../shared/data/real/phr_ventoux__left_image.geom``) ``n_scenes`` times, each copy's ground
offset moved along-track by ``(1 - overlap)`` of the scene length, so adjacent scenes overlap by
``overlap`` of their lines. Tie points lie in the overlaps (observed in both scenes, with a height
prior), GCPs in every ``gcp_every``-th scene and in the last one (observed in that scene), and a
random affine bias is injected per scene; image noise is ``noise_px``. The result is the dict of
``benchmarks.peers.strip.PROBLEM_SHAPES`` plus the truth, ``bias_true`` (S,6) and
``points_true`` (N,3), and ``gcp_scenes``, which the solvers ignore. A stand-in for the
Carto-2S strip simulation of jaxgeo.simulate.

All scenes share one viewing geometry (translated copies), as sub-scenes of one strip do: ties
then fix only the bias differences inside the overlaps, and the drift terms of scenes without GCPs
stay weakly determined (corner errors of a few px, within the formal precision).
"""

from __future__ import annotations

import numpy as np

from benchmarks.data import VENTOUX_LEFT_GEOM as RPC_GEOM
from benchmarks.peers.strip import enu_scale, project_biased, rpc_project

RPC_KEYS = ("num", "den", "ground_offset", "ground_scale", "image_offset", "image_scale")


def _real_rpc(path=RPC_GEOM) -> dict:
    import jaxgeo

    rpc = jaxgeo.read_rpc(path)
    return {k: np.asarray(getattr(rpc, k), dtype=float) for k in RPC_KEYS}


def _stack(rpc: dict, n: int) -> dict:
    return {k: np.repeat(v[None], n, axis=0) for k, v in rpc.items()}


def localize(rpcs: dict, scene, xy, h, iterations: int = 8) -> np.ndarray:
    """Unbiased RPC localisation by Newton on (lon, lat) at height ``h``: (m,2) px -> (m,3)."""
    scene = np.asarray(scene)
    ground = np.empty((len(xy), 3))
    ground[:, :2] = rpcs["ground_offset"][scene, :2]
    ground[:, 2] = h
    for _ in range(iterations):
        q, d = rpc_project(rpcs, scene, ground, jacobian=True)
        ground[:, :2] -= np.linalg.solve(d[:, :, :2], (q - xy)[..., None])[..., 0]
    return ground


def make_problem(
    n_scenes: int = 8,
    ties_per_pair: int = 10,
    seed: int = 0,
    *,
    overlap: float = 0.1,
    gcp_every: int = 4,
    gcps_per_scene: int = 6,
    noise_px: float = 0.3,
    gcp_sigma_m: float = 0.5,
    height_prior_sigma_m: float = 5.0,
    terrain_m: float = 300.0,
    shift_sigma_px: float = 3.0,
    matrix_sigma: float = 2e-5,
    rpc_path=RPC_GEOM,
) -> dict:
    """A synthetic strip of ``n_scenes`` biased RPC scenes (see the module docstring).

    Sizes: ``n_scenes - 1`` pairs of ``ties_per_pair`` ties (2 observations and a height prior
    each) plus ``gcps_per_scene`` GCPs (1 observation, 3 ground axes) per GCP scene. Biases:
    shifts ~ N(0, ``shift_sigma_px``), matrix entries ~ N(0, ``matrix_sigma``) (per px).
    """
    if n_scenes < 2 or ties_per_pair < 1:
        raise ValueError(
            f"need n_scenes >= 2 and ties_per_pair >= 1, got {n_scenes}, {ties_per_pair}"
        )
    rng = np.random.default_rng(seed)
    base = _real_rpc(rpc_path)
    width, height = 2 * base["image_offset"] + 1  # px: integer values at pixel centres
    h0 = base["ground_offset"][2]
    one = _stack(base, 1)
    # ground displacement per image line at the scene centre and the mean height
    centre = base["image_offset"][None]
    g = localize(one, [0, 0], np.concatenate([centre, centre + [0.0, 1000.0]]), h0)
    step = (1.0 - overlap) * height * (g[1, :2] - g[0, :2]) / 1000.0
    rpcs = _stack(base, n_scenes)
    rpcs["ground_offset"][:, :2] += np.arange(n_scenes)[:, None] * step

    points, obs_scene, obs_point = [], [], []
    margin = 0.02 * np.array([width, height])

    def add_points(scene, lo, hi, n, also_next):
        xy = rng.uniform(lo, hi, (n, 2))
        h = h0 + rng.uniform(-terrain_m, terrain_m, n)
        ground = localize(rpcs, np.full(n, scene), xy, h)
        first = sum(len(p) for p in points)
        points.append(ground)
        idx = first + np.arange(n)
        for s in (scene, scene + 1) if also_next else (scene,):
            obs_scene.append(np.full(n, s))
            obs_point.append(idx)
        return idx

    tie_idx = []
    for k in range(n_scenes - 1):  # overlap = the last `overlap` of scene k's lines
        lo = np.array([margin[0], (1 - overlap) * height + margin[1] / 4])
        hi = np.array([width - margin[0], height - margin[1] / 4])
        tie_idx.append(add_points(k, lo, hi, ties_per_pair, True))
    gcp_scenes = sorted(set(range(0, n_scenes, gcp_every)) | {n_scenes - 1})
    gcp_idx = []
    for k in gcp_scenes:  # GCPs away from the overlaps: seen in one scene only
        lo = np.array([margin[0], overlap * height + margin[1]])
        hi = np.array([width - margin[0], (1 - overlap) * height - margin[1]])
        gcp_idx.append(add_points(k, lo, hi, gcps_per_scene, False))
    points_true = np.concatenate(points)
    obs_scene, obs_point = np.concatenate(obs_scene), np.concatenate(obs_point)
    tie_idx, gcp_idx = np.concatenate(tie_idx), np.concatenate(gcp_idx)

    bias_true = np.concatenate(
        [
            rng.normal(0.0, shift_sigma_px, (n_scenes, 2)),
            rng.normal(0.0, matrix_sigma, (n_scenes, 4)),
        ],
        axis=1,
    )
    problem = dict(rpcs)
    xy_true = project_biased(problem, obs_scene, points_true[obs_point], bias_true)
    obs_xy = xy_true + rng.normal(0.0, noise_px, xy_true.shape)

    origin = np.array([*points_true[:, :2].mean(axis=0), h0])
    per_m = 1.0 / enu_scale(origin)  # (deg lon, deg lat, m) per metre
    gcp_obs = points_true[gcp_idx] + rng.normal(0.0, gcp_sigma_m, (len(gcp_idx), 3)) * per_m
    prior = points_true[tie_idx].copy()
    prior[:, 2] += rng.normal(0.0, height_prior_sigma_m, len(tie_idx))

    # initial ties: first observation localised at the prior height with no bias
    first = np.unique(obs_point, return_index=True)[1]
    points0 = points_true.copy()
    points0[tie_idx] = localize(
        rpcs, obs_scene[first][tie_idx], obs_xy[first][tie_idx], prior[:, 2]
    )
    points0[gcp_idx] = gcp_obs
    prior[:, :2] = points0[tie_idx, :2]  # unused (infinite sigma), kept finite

    problem.update(
        bias0=np.zeros((n_scenes, 6)),
        points0=points0,
        obs_scene=obs_scene,
        obs_point=obs_point,
        obs_xy=obs_xy,
        obs_sigma=np.full(len(obs_scene), noise_px),
        gcp_point=np.concatenate([gcp_idx, tie_idx]),
        gcp_lonlath=np.concatenate([gcp_obs, prior]),
        gcp_sigma_m=np.concatenate(
            [
                np.full((len(gcp_idx), 3), gcp_sigma_m),
                np.tile([np.inf, np.inf, height_prior_sigma_m], (len(tie_idx), 1)),
            ]
        ),
        origin=origin,
        bias_true=bias_true,
        points_true=points_true,
        gcp_scenes=np.asarray(gcp_scenes),
    )
    return problem
