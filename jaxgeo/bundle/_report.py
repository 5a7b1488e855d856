"""Accuracy reports as in tables 2-6 of 000_5aba1cb50921f3c6.txt.

- Image space, per image: RMS of ``x`` and ``y`` (px) of the differences between the measured
  image coordinates of the check points and the back-projection of their true coordinates.
- Object space: RMS, minimum and maximum of the check-point errors (estimated - true) in the
  local east/north/up frame of each true point (m).
- ``s0``, the a posteriori standard deviation of unit weight.

:func:`direct_georeferencing` gives the same figures without any GCP: the points are
intersected with the original models (table 3).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import numpy as np

from .. import geodesy
from .._runtime.kept import kept
from ..intersect import intersect
from ..io import GroundPoints, Observations


@dataclasses.dataclass(frozen=True)
class AccuracyReport:
    """One column of the paper's tables (see the module docstring).

    ``images``: name -> ``(rms_x_px, rms_y_px, n)``; ``ids``/``errors_m`` ``(n, 3)``: per check
    point, estimated - true in east/north/up metres; ``rms_m``/``min_m``/``max_m`` ``(3,)``.
    """

    title: str
    s0: float
    images: dict[str, tuple[float, float, int]]
    ids: tuple[str, ...]
    errors_m: np.ndarray
    rms_m: np.ndarray
    min_m: np.ndarray
    max_m: np.ndarray

    @property
    def n(self) -> int:
        return len(self.ids)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``s0``, ``checkpoints {n, rms_m, min_m, max_m}``, ``images {name:
        {rms_px: [x, y], n}}``."""

        def f(v):
            v = float(v)
            return v if np.isfinite(v) else None

        return {
            "title": self.title,
            "s0": f(self.s0),
            "checkpoints": {
                "n": self.n,
                "rms_m": [f(v) for v in self.rms_m],
                "min_m": [f(v) for v in self.min_m],
                "max_m": [f(v) for v in self.max_m],
            },
            "images": {
                name: {"rms_px": [f(x), f(y)], "n": int(n)}
                for name, (x, y, n) in self.images.items()
            },
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    def format(self) -> str:
        return format_reports([self])


def _stats(errors: np.ndarray):
    if errors.shape[0] == 0:
        nan = np.full(3, np.nan)
        return nan, nan, nan
    return np.sqrt(np.mean(errors**2, axis=0)), errors.min(axis=0), errors.max(axis=0)


def project(model, ground) -> np.ndarray:
    """``model.project`` compiled once per model structure and number of points, traced once
    across runs (a kept program, :mod:`jaxgeo._runtime.kept`; reports run at Python level)."""
    return np.asarray(_project(model, np.asarray(ground, float)))


@kept
def _project(model, ground):
    return model.project(ground)


@kept
def _enu(estimated, truth):
    return jax.vmap(geodesy.geodetic_to_enu)(estimated, truth)


def enu_errors(estimated: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``(n, 3)`` estimated - true in east/north/up metres about each true point."""
    if len(truth) == 0:
        return np.zeros((0, 3))
    return np.asarray(_enu(np.asarray(estimated, float), np.asarray(truth, float)))


def image_rms(
    models: Mapping[str, Any], observations: Observations, ground: GroundPoints, ids
) -> dict[str, tuple[float, float, int]]:
    """Per image RMS x, y (px) of back-projected true coordinates - measured, over ``ids``."""
    truth = {p: g for p, g in zip(ground.ids, ground.lonlath, strict=True)}
    wanted = set(ids)
    out = {}
    for name, model in models.items():
        # project every ground point of the image (whatever its role), select afterwards: the
        # compiled projection then does not depend on how the points are split into roles
        sel = [
            i
            for i, (p, img) in enumerate(
                zip(observations.point_ids, observations.images, strict=True)
            )
            if img == name and p in truth
        ]
        use = np.array([observations.point_ids[i] in wanted for i in sel], dtype=bool)
        if not use.any():
            out[name] = (float("nan"), float("nan"), 0)
            continue
        g = np.stack([truth[observations.point_ids[i]] for i in sel])
        d = (np.asarray(project(model, g)) - observations.xy[sel])[use]
        rms = np.sqrt(np.mean(d**2, axis=0))
        out[name] = (float(rms[0]), float(rms[1]), int(use.sum()))
    return out


def accuracy(
    models: Mapping[str, Any],
    observations: Observations,
    ground: GroundPoints,
    estimated: Mapping[str, Any],
    s0: float = float("nan"),
    title: str = "",
    role: str = "check",
) -> AccuracyReport:
    """Report on the points of ``role`` (check points) that were estimated (``{id: lonlath}``)."""
    keep = [i for i, p in enumerate(ground.ids) if p in estimated]  # all roles: see image_rms
    use = np.array([ground.role[i] == role for i in keep], dtype=bool)
    ids = tuple(ground.ids[i] for i, u in zip(keep, use, strict=True) if u)
    truth = ground.lonlath[keep].reshape(-1, 3)
    est = np.asarray([estimated[ground.ids[i]] for i in keep], dtype=float).reshape(-1, 3)
    errors = enu_errors(est, truth)[use]
    rms, lo, hi = _stats(errors)
    return AccuracyReport(
        title=title,
        s0=float(s0),
        images=image_rms(models, observations, ground, ids),
        ids=ids,
        errors_m=errors,
        rms_m=rms,
        min_m=lo,
        max_m=hi,
    )


def direct_georeferencing(
    models: Mapping[str, Any],
    observations: Observations,
    ground: GroundPoints,
    roles: Sequence[str] = ("gcp", "check"),
    title: str = "direct",
) -> AccuracyReport:
    """Table 3: forward intersection with the given (unadjusted) models, no GCP used.

    Every ground point of ``roles`` measured in at least two images is intersected; its
    error is intersected - true (ENU m); image RMS is back-projected true - measured;
    ``s0`` is that of the intersections, ``sqrt(sum r^2 / sum(2 n_rays - 3))``.
    """
    names = list(models)
    col = {n: c for c, n in enumerate(names)}
    wanted = [p for p, r in zip(ground.ids, ground.role, strict=True) if r in roles]
    row = {p: i for i, p in enumerate(wanted)}
    pts = np.full((len(wanted), len(names), 2), np.nan)
    sig = np.ones((len(wanted), len(names)))
    for p, img, xy, s in zip(
        observations.point_ids,
        observations.images,
        observations.xy,
        observations.sigma_px,
        strict=True,
    ):
        if p in row and img in col:
            pts[row[p], col[img]] = xy
            sig[row[p], col[img]] = s
    ok = np.sum(np.all(np.isfinite(pts), axis=-1), axis=1) >= 2
    ids = tuple(p for p, k in zip(wanted, ok, strict=True) if k)
    if ids:
        res = intersect([models[n] for n in names], pts[ok], sig[ok])
        est = np.asarray(res.ground)
        r2 = np.nansum((np.asarray(res.residuals_px) / sig[ok][..., None]) ** 2)
        dof = int(np.sum(2 * np.asarray(res.n_rays) - 3))
        s0 = float(np.sqrt(r2 / dof)) if dof > 0 else float("nan")
    else:
        est, s0 = np.zeros((0, 3)), float("nan")
    gidx = {p: i for i, p in enumerate(ground.ids)}
    truth = ground.lonlath[[gidx[p] for p in ids]].reshape(-1, 3)
    errors = enu_errors(est, truth)
    rms, lo, hi = _stats(errors)
    return AccuracyReport(
        title=title,
        s0=s0,
        images=image_rms(models, observations, ground, ids),
        ids=ids,
        errors_m=errors,
        rms_m=rms,
        min_m=lo,
        max_m=hi,
    )


def format_reports(reports: Sequence[AccuracyReport]) -> str:
    """The reports side by side, laid out like tables 2-6 of 000_ (one column group each)."""
    names = list(dict.fromkeys(n for r in reports for n in r.images))
    width = 12 * max(len(names), 1)

    def cell(text: str) -> str:
        return f"{text:>{width}}"

    def num(v, fmt=".2f"):
        return "-" if not np.isfinite(v) else format(v, fmt)

    lines = ["".ljust(22) + "".join(cell(r.title or "") for r in reports)]
    lines.append("".ljust(22) + "".join("".join(f"{n:>12}" for n in names) for _ in reports))
    for axis, label in ((0, "x"), (1, "y")):
        row = f"RMS_{label} [pixel]".ljust(22)
        for r in reports:
            row += "".join(f"{num(r.images.get(n, (np.nan,) * 3)[axis]):>12}" for n in names)
        lines.append(row)
    for axis, label in enumerate("ENU"):
        lines.append(
            f"RMS_{label} [m]".ljust(22) + "".join(cell(num(r.rms_m[axis])) for r in reports)
        )
        lines.append(
            f"R_{label} min/max [m]".ljust(22)
            + "".join(
                cell(f"{num(r.min_m[axis], '.1f')} / {num(r.max_m[axis], '.1f')}") for r in reports
            )
        )
    lines.append("s0".ljust(22) + "".join(cell(num(r.s0)) for r in reports))
    lines.append("check points".ljust(22) + "".join(cell(str(r.n)) for r in reports))
    return "\n".join(lines)
