"""Ground-point and image-observation tables (CSV), as ``jaxgeo adjust`` reads them.

``GROUND.csv`` — one row per ground point::

    id,lon,lat,h,role[,sigma_e_m,sigma_n_m,sigma_h_m]

``lon, lat`` in degrees (WGS84), ``h`` ellipsoidal height in metres, ``role`` ``gcp`` or ``check``
(check points are adjusted as tie points; their coordinates are only used to measure accuracy).
The sigmas are a priori standard deviations in metres (east, north, up); a missing column or an
empty cell takes the default (0.3 m, as in 000_5aba1cb50921f3c6.txt section 4).

``OBS.csv`` — one row per image measurement::

    id,image,x,y[,sigma_px]

``x, y`` = (column, row) in pixels, integer values at pixel centres, (0, 0) the centre of the first
pixel. ``sigma_px`` a priori standard deviation (default 0.5 px). A point id that appears in OBS
but not in GROUND is a tie point.

Errors name the file, the line and the column at fault; nothing is silently skipped. The data
types read and written here (:class:`GroundPoints`, :class:`Observations`) live in
:mod:`jaxgeo.io._observations` and are re-exported under their old names.
"""

from __future__ import annotations

import array
import csv
import io
import itertools
import math
import os
import pathlib

import numpy as np

from ..errors import JaxgeoError
from ._atomic import atomic_write_text
from ._observations import ROLES as ROLES
from ._observations import GroundPoints as GroundPoints
from ._observations import Observations as Observations

DEFAULT_GROUND_SIGMA_M = 0.3
DEFAULT_IMAGE_SIGMA_PX = 0.5


class TableError(JaxgeoError, ValueError):
    """A GROUND/OBS table that cannot be read; the message names file, line and column."""


def _float(value: str, where: str, column: str, allow_empty: bool = False) -> float:
    value = value.strip()
    if value == "" and allow_empty:
        return math.nan
    try:
        out = float(value)
    except ValueError:
        raise TableError(f"{where}: column {column!r} is not a number: {value!r}") from None
    if not math.isfinite(out):
        raise TableError(f"{where}: column {column!r} is not finite: {value!r}")
    return out


def _text(path: pathlib.Path) -> str:
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        return path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = path.read_bytes()[: err.start].count(b"\n") + 1
        raise TableError(f"{path}:{line}: not UTF-8 text ({err.reason})") from None


def _lines(text: str):
    """``(line number, line)`` of the lines that are neither blank nor comments, one at a time
    (a table of 200 000 rows is never held as a list of rows: its transient objects would stay
    in the interpreter's memory pools, ~100 MB, for the rest of an adjustment)."""
    for i, line in enumerate(io.StringIO(text, newline=None), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            yield i, line.rstrip("\n")


def _rows(path: pathlib.Path, required: tuple[str, ...]):
    text = _text(path)
    lines = _lines(text)

    def fields(lineno: int, line: str) -> list[str]:
        # one line at a time: a stray quote must not swallow the lines after it
        try:
            return next(csv.reader([line]), [])
        except csv.Error as err:
            raise TableError(f"{path}:{lineno}: {err}") from None

    first = next(lines, None)
    if first is None:
        raise TableError(f"{path}: empty table (expected header {','.join(required)})")
    header = [h.strip().lower() for h in fields(*first)]
    missing = [c for c in required if c not in header]
    if missing:
        raise TableError(
            f"{path}:{first[0]}: header lacks column(s) {', '.join(missing)} "
            f"(got {','.join(header)})"
        )
    for lineno, line in lines:
        row = fields(lineno, line)
        if len(row) != len(header):
            raise TableError(f"{path}:{lineno}: expected {len(header)} fields, got {len(row)}")
        yield lineno, dict(zip(header, (c.strip() for c in row), strict=True))


def table_lines(path: str | os.PathLike) -> np.ndarray:
    """The line number of every data row of a table (as read by :func:`read_ground` /
    :func:`read_observations`, in order), for messages that name the line at fault."""
    rows = itertools.islice(_lines(_text(pathlib.Path(path))), 1, None)
    return np.fromiter((lineno for lineno, _ in rows), dtype=np.int64)


def read_ground(
    path: str | os.PathLike, default_sigma_m: float = DEFAULT_GROUND_SIGMA_M
) -> GroundPoints:
    """Read a GROUND.csv table (see the module docstring)."""
    path = pathlib.Path(path)
    ids, coords, roles, sigmas = [], [], [], []
    seen: dict[str, int] = {}
    for lineno, row in _rows(path, ("id", "lon", "lat", "h", "role")):
        where = f"{path}:{lineno}"
        pid = row["id"]
        if not pid:
            raise TableError(f"{where}: empty point id")
        if pid in seen:
            raise TableError(f"{where}: point id {pid!r} already given on line {seen[pid]}")
        seen[pid] = lineno
        lon, lat, h = (_float(row[c], where, c) for c in ("lon", "lat", "h"))
        if not (-180.0 <= lon <= 360.0 and -90.0 <= lat <= 90.0):
            raise TableError(f"{where}: point {pid!r} has lon/lat out of range: {lon}, {lat}")
        role = row["role"].lower()
        if role not in ROLES:
            raise TableError(
                f"{where}: point {pid!r} has role {row['role']!r}; expected gcp or check"
            )
        sig = [
            _float(row.get(c, ""), where, c, allow_empty=True)
            for c in ("sigma_e_m", "sigma_n_m", "sigma_h_m")
        ]
        sig = [default_sigma_m if math.isnan(s) else s for s in sig]
        if any(s <= 0 for s in sig):
            raise TableError(f"{where}: point {pid!r} has a non-positive sigma")
        ids.append(pid)
        coords.append((lon, lat, h))
        roles.append(role)
        sigmas.append(sig)
    return GroundPoints(
        tuple(ids),
        np.asarray(coords, dtype=float).reshape(-1, 3),
        tuple(roles),
        np.asarray(sigmas, dtype=float).reshape(-1, 3),
    )


def read_observations(
    path: str | os.PathLike, default_sigma_px: float = DEFAULT_IMAGE_SIGMA_PX
) -> Observations:
    """Read an OBS.csv table (see the module docstring); one without rows is refused."""
    path = pathlib.Path(path)
    pids: list[str] = []
    same: dict[str, str] = {}  # point id -> its first string: one string per point, not per row
    code: dict[str, int] = {}  # image name -> its number: one string per image, not per row
    values, images, lines = array.array("d"), array.array("q"), array.array("q")
    for lineno, row in _rows(path, ("id", "image", "x", "y")):
        where = f"{path}:{lineno}"
        pid, image = row["id"], row["image"]
        if not pid or not image:
            raise TableError(f"{where}: empty point id or image name")
        x, y = _float(row["x"], where, "x"), _float(row["y"], where, "y")
        s = _float(row.get("sigma_px", row.get("sigma", "")), where, "sigma_px", allow_empty=True)
        s = default_sigma_px if math.isnan(s) else s
        if s <= 0:
            raise TableError(f"{where}: point {pid!r} has a non-positive sigma_px")
        pids.append(same.setdefault(pid, pid))
        images.append(code.setdefault(image, len(code)))
        values.extend((x, y, s))
        lines.append(lineno)
    if not pids:  # (an adjustment without measurements fails deep inside, naming nothing)
        raise TableError(f"{path}: no measurements: the table has a header but no rows "
                         "(id,image,x,y[,sigma_px])")  # fmt: skip
    names = list(code)
    image_no = np.frombuffer(images, dtype=np.int64)
    _refuse_repeats(path, pids, image_no, np.frombuffer(lines, dtype=np.int64), names)
    xys = np.frombuffer(values, dtype=float).reshape(-1, 3)
    return Observations(
        tuple(pids), tuple(names[k] for k in image_no), xys[:, :2].copy(), xys[:, 2].copy()
    )


def _refuse_repeats(path, pids: list[str], image_no: np.ndarray, lines: np.ndarray, names):
    """The first row (in the file) that measures a point again in the same image."""
    number: dict[str, int] = {}
    ids = np.fromiter((number.setdefault(p, len(number)) for p in pids), np.int64, len(pids))
    order = np.lexsort((np.arange(ids.size), image_no, ids))  # by point, image, then row
    a, b = order[:-1], order[1:]
    again = b[(ids[a] == ids[b]) & (image_no[a] == image_no[b])]
    if again.size:
        k = int(again.min())
        first = int(a[np.flatnonzero(b == k)[0]])  # the row before it in its group: the first
        raise TableError(
            f"{path}:{lines[k]}: point {pids[k]!r} in image {names[image_no[k]]!r} already "
            f"measured on line {lines[first]}"
        )


def _csv(header: list[str], rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def write_ground(points: GroundPoints, path: str | os.PathLike, overwrite: bool = False):
    """Write a GROUND.csv table atomically (full float64 precision)."""
    cols = (points.ids, points.lonlath, points.role, points.sigma_m)
    rows = [
        [pid, *(repr(float(v)) for v in c), role, *(repr(float(s)) for s in sig)]
        for pid, c, role, sig in zip(*cols, strict=True)
    ]
    header = ["id", "lon", "lat", "h", "role", "sigma_e_m", "sigma_n_m", "sigma_h_m"]
    return atomic_write_text(path, _csv(header, rows), overwrite=overwrite)


def write_observations(obs: Observations, path: str | os.PathLike, overwrite: bool = False):
    """Write an OBS.csv table atomically (full float64 precision)."""
    rows = [
        [pid, img, repr(float(p[0])), repr(float(p[1])), repr(float(s))]
        for pid, img, p, s in zip(obs.point_ids, obs.images, obs.xy, obs.sigma_px, strict=True)
    ]
    return atomic_write_text(path, _csv(["id", "image", "x", "y", "sigma_px"], rows), overwrite)
