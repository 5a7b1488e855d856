"""A strip as delivered: sub-scenes with their line offsets and RPCs, GCPs, measurements.

On disk (what ``jaxgeo simulate carto2s-strip`` writes, and what a user assembles from a
Carto-2S delivery): ``strip.json`` listing the sub-scenes in strip order ::

    {"scenes": [{"name": "scene_000", "rpc": "scene_000.txt", "first_line": 0,
                 "n_rows": 48000, "n_cols": 24000}, ...]}

(RPC paths relative to the json file, any format :func:`jaxgeo.io.read_rpc` knows; optional
``first_col``), ``ground.csv`` (GCPs and check points) and ``observations.csv`` (their
measurements, image = sub-scene name).
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
from collections.abc import Iterable

import numpy as np

from ..io import (
    GroundPoints,
    Observations,
    RPCFormatError,
    read_ground,
    read_observations,
    read_rpc,
)
from ..models import RPC
from ._errors import StripFormatError


@dataclasses.dataclass(frozen=True)
class SubScene:
    """One sub-scene of a strip: its name, first strip line, and size in pixels."""

    name: str
    line_offset: int
    n_rows: int
    n_cols: int
    col_offset: int = 0


@dataclasses.dataclass(frozen=True)
class StripFiles:
    """The files a strip was read from (:func:`read_strip`): messages name them, outputs are
    never written over them."""

    description: pathlib.Path
    ground: pathlib.Path
    observations: pathlib.Path
    rpcs: tuple[pathlib.Path, ...]

    def all(self) -> tuple[pathlib.Path, ...]:
        return (self.description, self.ground, self.observations, *self.rpcs)


@dataclasses.dataclass(frozen=True)
class Strip:
    """Sub-scenes in strip order with their RPCs, ground points and image measurements;
    ``files`` the files it was read from (``None`` when made in memory)."""

    scenes: tuple[SubScene, ...]
    rpcs: dict[str, RPC]
    ground: GroundPoints
    observations: Observations
    files: StripFiles | None = None

    def __post_init__(self):
        names = [s.name for s in self.scenes]
        if len(set(names)) != len(names):
            raise StripFormatError(f"duplicate sub-scene names in the strip: {names}")
        missing = [n for n in names if n not in self.rpcs]
        if missing:
            raise StripFormatError(f"no RPC for sub-scene(s) {missing}")
        unknown = sorted(set(self.observations.images) - set(names))
        if unknown:
            raise StripFormatError(
                f"observations name image(s) {unknown[:5]} that are not sub-scenes of the strip"
            )

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.scenes)

    def __len__(self) -> int:
        return len(self.scenes)

    def scene_index(self, name: str) -> int:
        return self.names.index(name)

    def gcp_scenes(self) -> list[int]:
        """Indices of the sub-scenes in which at least one GCP is measured."""
        gcp = {p for p, r in zip(self.ground.ids, self.ground.role, strict=True) if r == "gcp"}
        index = {n: k for k, n in enumerate(self.names)}
        return sorted(
            {index[i] for p, i in zip(self.observations.point_ids, self.observations.images,
                                      strict=True) if p in gcp}
        )  # fmt: skip

    def with_gcp_scenes(self, keep: Iterable[int]) -> Strip:
        """A copy where GCPs measured only outside the sub-scenes ``keep`` become check points."""
        keep_names = {self.names[k] for k in keep}
        seen_in: dict[str, set[str]] = {}
        for p, i in zip(self.observations.point_ids, self.observations.images, strict=True):
            seen_in.setdefault(p, set()).add(i)
        roles = {
            p: "check"
            for p, r in zip(self.ground.ids, self.ground.role, strict=True)
            if r == "gcp" and not (seen_in.get(p, set()) & keep_names)
        }
        return dataclasses.replace(self, ground=self.ground.with_roles(roles))

    @classmethod
    def from_simulation(cls, sim) -> Strip:
        """The strip of a :class:`jaxgeo.simulate._carto2s.StripScene` (vendor RPCs)."""
        scenes = tuple(
            SubScene(n, int(sim.first_rows[k]), int(sim.scene_rows), int(sim.n_cols))
            for k, n in enumerate(sim.names)
        )
        return cls(scenes, dict(sim.vendor), sim.ground, sim.observations)


def _field(entry: dict, key: str, path, k: int, kind=int):
    if key not in entry:
        raise StripFormatError(f"{path}: scene #{k} ({entry.get('name', '?')!r}) lacks {key!r}")
    try:
        return kind(entry[key])
    except (TypeError, ValueError) as e:
        raise StripFormatError(
            f"{path}: scene #{k} ({entry.get('name', '?')!r}): {key!r} = {entry[key]!r} is not "
            f"a valid {kind.__name__}"
        ) from e


def read_strip(
    path: str | os.PathLike,
    ground: str | os.PathLike | None = None,
    observations: str | os.PathLike | None = None,
) -> Strip:
    """Read ``strip.json`` (or a directory holding it) with its RPCs, ground and observations.

    ``ground``/``observations`` default to ``ground.csv``/``observations.csv`` beside it.
    """
    path = pathlib.Path(path)
    if path.is_dir():
        path = path / "strip.json"
    try:
        desc = json.loads(path.read_text())
    except FileNotFoundError as e:
        raise StripFormatError(f"{path}: no such strip description") from e
    except json.JSONDecodeError as e:
        raise StripFormatError(f"{path}:{e.lineno}: not valid JSON ({e.msg})") from e
    entries = desc.get("scenes") if isinstance(desc, dict) else None
    if not isinstance(entries, list) or not entries:
        raise StripFormatError(f"{path}: expected a non-empty list under 'scenes'")
    scenes, rpcs, rpc_files = [], {}, []
    for k, e in enumerate(entries):
        if not isinstance(e, dict):
            raise StripFormatError(f"{path}: scene #{k} is not an object")
        name = _field(e, "name", path, k, str)
        scenes.append(
            SubScene(
                name,
                _field(e, "first_line", path, k),
                _field(e, "n_rows", path, k),
                _field(e, "n_cols", path, k),
                int(e.get("first_col", 0)),
            )
        )
        rpc_path = path.parent / _field(e, "rpc", path, k, str)
        rpc_files.append(rpc_path)
        try:
            rpcs[name] = read_rpc(rpc_path)
        except FileNotFoundError as err:
            raise StripFormatError(
                f"{path}: RPC file of scene {name!r} not found: {rpc_path}"
            ) from err
        except RPCFormatError as err:
            raise StripFormatError(f"{path}: RPC of scene {name!r}: {err}") from err
    order = np.argsort([s.line_offset for s in scenes], kind="stable")
    if not np.array_equal(order, np.arange(len(scenes))):
        raise StripFormatError(f"{path}: sub-scenes must be listed in strip order (first_line)")
    files = StripFiles(
        path,
        pathlib.Path(ground) if ground else path.parent / "ground.csv",
        pathlib.Path(observations) if observations else path.parent / "observations.csv",
        tuple(rpc_files),
    )
    g = read_ground(files.ground)
    o = read_observations(files.observations)
    try:
        return Strip(tuple(scenes), rpcs, g, o, files)
    except StripFormatError as err:
        raise StripFormatError(f"{path} with {files.observations}: {err}") from err
