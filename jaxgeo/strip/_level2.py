"""Level 2 of the full-strip adjustment (003_ s. 7 and 9): what it needs besides level 1.

Every GCP measurement (a GCP seen in two sub-scenes gives two rows), every check measurement,
and the formed ties (for the continuity figures), as index arrays into the strip's sub-scenes
in the level-1 block order.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._delivery import Strip
from ._level1 import Level1Input


class Level2Data(eqx.Module):
    """What level 2 needs besides the level-1 solution (indices into the strip's sub-scenes).

    GCPs: ``gcp_scene`` (g,), ``gcp_xy`` (g, 2) px, ``gcp_lonlath`` (g, 3) surveyed (every
    GCP measurement; a GCP seen in two sub-scenes gives two rows), ``gcp_group`` (G, g) 0/1
    the measurements of each sub-scene with GCPs (for cross-validation). Check points:
    ``check_scene`` (c,), ``check_xy`` (c, 2) px, ``check_lonlath`` (c, 3) surveyed.
    Tie points, for the continuity figures: ``tie_scene`` (t, 2) the two sub-scenes,
    ``tie_xy`` (t, 2, 2) px in each, ``tie_h`` (t,) m.
    Gross errors: ``gcp_weight`` (g,) the weight of each GCP measurement in the level-2 fit (0:
    removed as a gross error, at level 1 or 2; below 1: a robust loss' IRLS weight),
    ``gcp_sigma_m`` (g,) its a priori sigma per ground axis (m: the surveyed coordinates' and the
    measurement's, one pixel taken as the sub-scene's ground sample distance).
    """

    gcp_scene: Int[Array, " g"]
    gcp_xy: Float[Array, "g 2"]
    gcp_lonlath: Float[Array, "g 3"]
    gcp_group: Float[Array, "G g"]
    check_scene: Int[Array, " c"]
    check_xy: Float[Array, "c 2"]
    check_lonlath: Float[Array, "c 3"]
    tie_scene: Int[Array, "t 2"]
    tie_xy: Float[Array, "t 2 2"]
    tie_h: Float[Array, " t"]
    gcp_weight: Float[Array, " g"]
    gcp_sigma_m: Float[Array, " g"]


def level2_input(
    strip: Strip, inp: Level1Input, block_of: np.ndarray, gsd_m: np.ndarray | None = None
) -> tuple[Level2Data, dict[str, list[int]]]:
    """The :class:`Level2Data` of ``strip`` (``block_of`` (S,): the level-1 block of each
    sub-scene; ``gsd_m`` (S,): each sub-scene's ground sample distance, m, default 1) and the
    strip's observation rows of the GCP and check measurements
    (``{"gcp": [...], "check": [...]}``). Every GCP measurement has weight 1."""
    o, g = strip.observations, strip.ground
    index = {p: i for i, p in enumerate(g.ids)}
    scene = {n: k for k, n in enumerate(strip.names)}
    rows: dict[str, list[int]] = {"gcp": [], "check": []}
    for i, p in enumerate(o.point_ids):
        if p in index:
            rows[g.role[index[p]]].append(i)
    t = inp.ties
    pair = np.argsort(t.point, kind="stable").reshape(-1, 2)  # (t, 2) rows: scene k, k + 1

    def lonlath(r):
        return jnp.asarray(g.lonlath[[index[o.point_ids[i]] for i in r]].reshape(-1, 3))

    def scenes(r):
        return jnp.asarray(block_of[[scene[o.images[i]] for i in r]].astype(np.int64))

    gcp_scene = np.array([scene[o.images[i]] for i in rows["gcp"]], dtype=int)
    gsd = np.ones(len(strip.names)) if gsd_m is None else np.asarray(gsd_m, dtype=float)
    r_g = rows["gcp"]
    surveyed = g.sigma_m[[index[o.point_ids[i]] for i in r_g]].reshape(-1, 3)[:, :2]
    finite = np.where(np.isfinite(surveyed), surveyed, 0.0)
    sigma = np.hypot(np.sqrt(np.mean(finite**2, axis=1)), o.sigma_px[r_g] * gsd[gcp_scene])
    groups = np.unique(gcp_scene)
    group = (gcp_scene[None, :] == groups[:, None]).astype(float).reshape(len(groups), -1)

    return Level2Data(
        gcp_scene=scenes(rows["gcp"]),
        gcp_xy=jnp.asarray(o.xy[rows["gcp"]].reshape(-1, 2)),
        gcp_lonlath=lonlath(rows["gcp"]),
        gcp_group=jnp.asarray(group),
        check_scene=scenes(rows["check"]),
        check_xy=jnp.asarray(o.xy[rows["check"]].reshape(-1, 2)),
        check_lonlath=lonlath(rows["check"]),
        tie_scene=jnp.asarray(block_of[t.scene[pair]].astype(np.int64)),
        tie_xy=jnp.asarray(t.xy[pair]),
        tie_h=jnp.asarray(inp.tie_lonlath[:, 2]),
        gcp_weight=jnp.ones(len(r_g)),
        gcp_sigma_m=jnp.asarray(sigma.reshape(-1)),
    ), rows
