"""A tile plan: the tiles of a raster product, each with its output window and what it reads.

A plan is plain data (JSON): the product's size, the tiles in row-major order, each with an id
(``r0003c0007``: tile row 3, tile column 7), its output window ``(row, col, rows, cols)`` in
product pixels and ``inputs``, a JSON object of what the tile reads (its ground box, its image
and DEM windows, margins included; each kind of job says what it puts there), and ``job``, the
parameters of the whole job (inputs, grid, options). Users who submit tiles to their own
scheduler read it (``jaxgeo ortho ... --plan plan.json``); the runner keeps a copy in its work
folder so that ``--resume`` refuses a folder of another job (:meth:`TilePlan.fingerprint`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import pathlib
from collections.abc import Callable

from ..errors import JaxgeoError
from ..io.internal import atomic_write_text

PLAN_FORMAT = "jaxgeo-tile-plan/1"
"""The ``format`` entry of a plan file (bumped when its layout changes)."""


class PlanError(JaxgeoError, ValueError):
    """A tile plan that cannot be used (unreadable, another format, inconsistent)."""


@dataclasses.dataclass(frozen=True)
class Tile:
    """One tile: ``id``; output window ``row, col`` (first product pixel) and ``rows, cols``
    (px); ``inputs``: what it reads (JSON object, job-specific: ground box, image window...)."""

    id: str
    row: int
    col: int
    rows: int
    cols: int
    inputs: dict = dataclasses.field(default_factory=dict, compare=False)

    @property
    def cost(self) -> float:
        """The tile's expected work, relative to the others': ``inputs["cost"]`` where the job
        gives one (a DSM tile: the reference image's pixels it reads), else its output pixels.
        The runner starts the costliest tiles first (the run then ends on small ones)."""
        return float(self.inputs.get("cost", self.rows * self.cols))

    def describe(self) -> str:
        """``tile r0001c0002 (rows 1024..2047, cols 2048..3071)``: for messages."""
        return (
            f"tile {self.id} (rows {self.row}..{self.row + self.rows - 1}, "
            f"cols {self.col}..{self.col + self.cols - 1})"
        )

    def to_dict(self) -> dict:
        return {"id": self.id, "row": self.row, "col": self.col, "rows": self.rows,
                "cols": self.cols, "inputs": self.inputs}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class TilePlan:
    """The tiles of one product: ``kind`` (``"ortho"``, ``"dsm"``), the product's ``width`` and
    ``height`` (px), the regular ``tile_px`` and the ``margin_px`` each tile reads around its
    window, the ``tiles`` (row-major) and ``job`` (JSON object: the job's parameters)."""

    kind: str
    width: int
    height: int
    tile_px: int
    margin_px: int
    tiles: tuple[Tile, ...]
    job: dict = dataclasses.field(default_factory=dict, compare=False)

    def __post_init__(self):
        ids = [t.id for t in self.tiles]
        if len(set(ids)) != len(ids):
            raise PlanError(f"{self.kind} plan: tile ids repeat")

    def __len__(self) -> int:
        return len(self.tiles)

    def tile(self, tile_id: str) -> Tile:
        """The tile named ``tile_id`` (``KeyError`` naming it if the plan has none)."""
        for t in self.tiles:
            if t.id == tile_id:
                return t
        raise KeyError(f"{self.kind} plan has no tile {tile_id!r}")

    def to_dict(self) -> dict:
        return {
            "format": PLAN_FORMAT,
            "kind": self.kind,
            "width": self.width,
            "height": self.height,
            "tile_px": self.tile_px,
            "margin_px": self.margin_px,
            "n_tiles": len(self.tiles),
            "job": self.job,
            "tiles": [t.to_dict() for t in self.tiles],
        }

    def to_json(self, indent: int | None = 1) -> str:
        return json.dumps(self.to_dict(), indent=indent, sort_keys=False) + "\n"

    @classmethod
    def from_dict(cls, data: dict, source: str = "plan") -> TilePlan:
        if data.get("format") != PLAN_FORMAT:
            raise PlanError(f"{source}: not a jaxgeo tile plan (format {data.get('format')!r}, "
                            f"expected {PLAN_FORMAT!r})")  # fmt: skip
        try:
            tiles = tuple(
                Tile(
                    str(t["id"]),
                    int(t["row"]),
                    int(t["col"]),
                    int(t["rows"]),
                    int(t["cols"]),
                    dict(t.get("inputs", {})),
                )  # fmt: skip
                for t in data["tiles"]
            )
            return cls(str(data["kind"]), int(data["width"]), int(data["height"]),
                       int(data["tile_px"]), int(data["margin_px"]), tiles,
                       dict(data.get("job", {})))  # fmt: skip
        except (KeyError, TypeError, ValueError) as err:
            raise PlanError(f"{source}: damaged tile plan ({err})") from None

    def fingerprint(self) -> str:
        """SHA-256 of the plan's canonical JSON: equal for the same job, tiles and inputs."""
        text = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()


def plan_tiles(
    kind: str,
    width: int,
    height: int,
    tile_px: int,
    margin_px: int = 0,
    job: dict | None = None,
    inputs: Callable[[Tile], dict] | None = None,
) -> TilePlan:
    """A regular plan of ``tile_px`` square tiles over a ``width`` x ``height`` px product (the
    last row and column of tiles are cut by the product's edge). ``inputs(tile)`` gives each
    tile's ``inputs`` entry; ``job`` the plan's."""
    if width < 1 or height < 1:
        raise PlanError(f"{kind} plan: empty product {width} x {height} px")
    if tile_px < 1:
        raise PlanError(f"{kind} plan: tile size must be >= 1 px, got {tile_px}")
    n_rows, n_cols = math.ceil(height / tile_px), math.ceil(width / tile_px)
    digits = max(4, len(str(max(n_rows, n_cols))))
    tiles = []
    for i in range(n_rows):
        for j in range(n_cols):
            r, c = i * tile_px, j * tile_px
            tile = Tile(f"r{i:0{digits}d}c{j:0{digits}d}", r, c, min(tile_px, height - r),
                        min(tile_px, width - c))  # fmt: skip
            if inputs is not None:
                tile = dataclasses.replace(tile, inputs=dict(inputs(tile)))
            tiles.append(tile)
    return TilePlan(kind, int(width), int(height), int(tile_px), int(margin_px), tuple(tiles),
                    dict(job or {}))  # fmt: skip


def write_plan(plan: TilePlan, path: str | os.PathLike, overwrite: bool = False) -> pathlib.Path:
    """``plan`` as JSON at ``path`` (atomic; an existing file only with ``overwrite``)."""
    return atomic_write_text(path, plan.to_json(), overwrite=overwrite)


def read_plan(path: str | os.PathLike) -> TilePlan:
    """The plan in the JSON file ``path`` (:class:`PlanError` naming it when it is not one)."""
    path = pathlib.Path(path)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise PlanError(f"{path}: not JSON ({err})") from None
    if not isinstance(data, dict):
        raise PlanError(f"{path}: not a jaxgeo tile plan")
    return TilePlan.from_dict(data, source=str(path))
