"""Scene metadata: the approximate geometry that initialises physical sensor models.

One :class:`SceneMetadata` per image: size, corner coordinates, nominal flying height, view
angles, camera constants and line timing. :func:`read_metadata` reads two formats, one scene or
several per file:

**Cartosat-1-like text** -- ``key = value`` lines; ``#`` starts a comment; keys are
case-insensitive; unknown keys (vendor files carry many) are ignored. A ``[name]`` line starts a
new scene (its ``image_id`` defaults to ``name``); a file without sections holds one scene.

==========================  ==============================================  ==================
key                         meaning                                         aliases
==========================  ==============================================  ==================
image_id                    scene identifier (text)                         ProductID, SceneID
n_cols, n_rows              image size in pixels (columns, rows = lines)    NoPixels, NoScans
ul_lon_deg, ul_lat_deg      upper-left corner (x = 0, y = 0), WGS84 deg     ProdULLon, ProdULLat
ur_lon_deg, ur_lat_deg      upper-right corner (x = n_cols-1, y = 0)        ProdURLon, ProdURLat
lr_lon_deg, lr_lat_deg      lower-right corner (x = n_cols-1, y = n_rows-1) ProdLRLon, ProdLRLat
ll_lon_deg, ll_lat_deg      lower-left corner (x = 0, y = n_rows-1)         ProdLLLon, ProdLLLat
ul_h_m ... ll_h_m           corner ellipsoidal heights (optional)
corner_h_m                  height of every corner without its own (def. 0)
flying_height_m             nominal orbit altitude above the ellipsoid (m)
along_track_angle_deg       view angle along track, + forward (fore +26)
across_track_angle_deg      view angle across track (optional, default 0)
focal_length_mm             focal length (optional)
pixel_size_um               detector pitch (optional)
line_time_s                 time per image line (optional; 0.336e-3)
first_line_time_s           time of line 0 after the sequence epoch (def. 0)
epoch_utc                   the sequence epoch, ISO 8601 text (optional)
==========================  ==============================================  ==================

**JSON** -- an object with the :class:`SceneMetadata` field names (``corners`` a 4 x 3 list of
``[lon_deg, lat_deg, h_m]`` in the order UL, UR, LR, LL), a list of such objects, or
``{"scenes": [...]}``. :func:`write_metadata_json` writes that format.

Errors name the file, the scene, every missing field, and the key and line of a bad value.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pathlib
import re
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from ..errors import JaxgeoError
from ..models import SceneMetadata as SceneMetadata
from ..models.internal import SCENE_FLOAT_FIELDS
from ._atomic import atomic_write_text

CORNER_NAMES = ("ul", "ur", "lr", "ll")
"""Corner order of :attr:`SceneMetadata.corners`: UL (0, 0), UR, LR, LL."""


class MetadataError(JaxgeoError, ValueError):
    """A metadata file that cannot be read; the message names the file (and line or scene)."""


_REQUIRED = ("image_id", "n_cols", "n_rows", "corners", "flying_height_m", "along_track_angle_deg")


# --- text -------------------------------------------------------------------------------

_ALIASES = {
    "productid": "image_id",
    "sceneid": "image_id",
    "nopixels": "n_cols",
    "noscans": "n_rows",
    **{f"prod{c}{ll}": f"{c}_{ll}_deg" for c in CORNER_NAMES for ll in ("lon", "lat")},
}
_SECTION = re.compile(r"^\[\s*([^\]]+?)\s*\]$")


def _canonical_key(key: str) -> str:
    k = key.strip().lower()
    return _ALIASES.get(k, k)


def _parse_text(text: str, path: str) -> list[dict[str, tuple[str, int]]]:
    """Split into scenes of ``{key: (value, line_number)}``."""
    scenes: list[dict[str, tuple[str, int]]] = []
    current: dict[str, tuple[str, int]] | None = None
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        section = _SECTION.match(line)
        if section:
            current = {"image_id": (section.group(1), number)}
            scenes.append(current)
            continue
        if "=" not in line:
            raise MetadataError(
                f"{path}:{number}: expected 'key = value' or '[scene]', got {raw!r}"
            )
        key, value = line.split("=", 1)
        key = _canonical_key(key)
        if current is None:
            current = {}
            scenes.append(current)
        if key in current and key != "image_id":
            raise MetadataError(
                f"{path}:{number}: duplicate key {key!r} (first on line {current[key][1]}); "
                "start each further scene with a '[name]' line"
            )
        current[key] = (value.strip(), number)
    if not scenes:
        raise MetadataError(f"{path}: no scene metadata found (empty file)")
    return scenes


def _number(path: str, key: str, value: str | float, line: int | None) -> float:
    where = f"{path}:{line}" if line is not None else path
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError):  # OverflowError: a 400-digit JSON integer
        raise MetadataError(f"{where}: {key} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise MetadataError(f"{where}: {key} must be finite, got {value!r}")
    return x


def _integer(path: str, key: str, value: Any, line: int | None) -> int:
    x = _number(path, key, value, line)
    if x != int(x):
        where = f"{path}:{line}" if line is not None else path
        raise MetadataError(f"{where}: {key} must be an integer, got {value!r}")
    return int(x)


def _scene_from_text(entries: dict[str, tuple[str, int]], path: str, index: int) -> SceneMetadata:
    name = entries.get("image_id", (f"#{index}", None))[0]
    corner_keys = [f"{c}_{ll}_deg" for c in CORNER_NAMES for ll in ("lon", "lat")]
    required = ["image_id", "n_cols", "n_rows", *corner_keys, "flying_height_m"]
    required.append("along_track_angle_deg")
    missing = [k for k in required if k not in entries]
    if missing:
        raise MetadataError(
            f"{path}: scene {name!r} is missing required field(s): {', '.join(missing)}"
        )

    def num(key):
        value, line = entries[key]
        return _number(path, key, value, line)

    h0 = num("corner_h_m") if "corner_h_m" in entries else 0.0
    corners = [
        [num(f"{c}_lon_deg"), num(f"{c}_lat_deg"), num(f"{c}_h_m") if f"{c}_h_m" in entries else h0]
        for c in CORNER_NAMES
    ]
    kwargs: dict[str, Any] = {
        "image_id": entries["image_id"][0],
        "n_cols": _integer(path, "n_cols", *entries["n_cols"]),
        "n_rows": _integer(path, "n_rows", *entries["n_rows"]),
        "corners": corners,
    }
    for key in SCENE_FLOAT_FIELDS:
        if key in entries:
            kwargs[key] = num(key)
    if "epoch_utc" in entries:
        kwargs["epoch_utc"] = entries["epoch_utc"][0]
    try:
        return SceneMetadata(**kwargs)
    except ValueError as err:
        raise MetadataError(f"{path}: {err}") from None


# --- JSON -------------------------------------------------------------------------------

_FIELDS = tuple(f.name for f in dataclasses.fields(SceneMetadata))


def _scene_from_json(obj: Any, path: str, index: int) -> SceneMetadata:
    if not isinstance(obj, dict):
        raise MetadataError(
            f"{path}: scene #{index} must be a JSON object, got {type(obj).__name__}"
        )
    name = obj.get("image_id", f"#{index}")
    missing = [k for k in _REQUIRED if k not in obj]
    if missing:
        raise MetadataError(
            f"{path}: scene {name!r} is missing required field(s): {', '.join(missing)}"
        )
    unknown = sorted(set(obj) - set(_FIELDS))
    if unknown:
        raise MetadataError(f"{path}: scene {name!r} has unknown field(s): {', '.join(unknown)}")
    kwargs = dict(obj)
    kwargs["image_id"] = str(obj["image_id"])
    for key in ("n_cols", "n_rows"):
        kwargs[key] = _integer(path, f"scene {name!r} {key}", obj[key], None)
    for key in SCENE_FLOAT_FIELDS:
        if obj.get(key) is not None:
            kwargs[key] = _number(path, f"scene {name!r} {key}", obj[key], None)
    try:
        corners = np.array(obj["corners"], dtype=float)
    except (TypeError, ValueError, OverflowError):
        msg = f"{path}: scene {name!r} corners must be a 4 x 3 list of numbers"
        raise MetadataError(msg) from None
    kwargs["corners"] = corners
    try:
        return SceneMetadata(**kwargs)
    except ValueError as err:
        raise MetadataError(f"{path}: {err}") from None


# --- public functions -------------------------------------------------------------------


def read_metadata(path: str | os.PathLike) -> list[SceneMetadata]:
    """Read one or several scenes from a Cartosat-1-like text file or a JSON file.

    JSON is recognised by a ``.json`` suffix or content starting with ``{`` or ``[`` (a text
    file may start with a ``[scene]`` line). Returns the scenes in file order.
    """
    path = pathlib.Path(path)
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as err:
        line = path.read_bytes()[: err.start].count(b"\n") + 1
        raise MetadataError(f"{path}:{line}: not UTF-8 text ({err.reason})") from None
    stripped = text.lstrip()
    first_line = stripped.split("\n", 1)[0].split("#", 1)[0].strip()
    is_json = path.suffix.lower() == ".json" or stripped.startswith("{")
    is_json |= stripped.startswith("[") and not _SECTION.match(first_line)
    if is_json:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise MetadataError(f"{path}:{err.lineno}: invalid JSON: {err.msg}") from None
        except (ValueError, RecursionError) as err:  # e.g. an integer of over 4300 digits
            raise MetadataError(f"{path}: invalid JSON: {err}") from None
        if isinstance(data, dict) and "scenes" in data:
            data = data["scenes"]
        items = data if isinstance(data, list) else [data]
        if not items:
            raise MetadataError(f"{path}: no scene metadata found (empty list)")
        return [_scene_from_json(obj, str(path), i) for i, obj in enumerate(items)]
    return [_scene_from_text(s, str(path), i) for i, s in enumerate(_parse_text(text, str(path)))]


def write_metadata_json(
    scenes: SceneMetadata | Sequence[SceneMetadata] | Iterable[SceneMetadata],
    path: str | os.PathLike,
    overwrite: bool = False,
) -> pathlib.Path:
    """Write scenes as a JSON list, atomically (temporary file + rename).

    Raises ``FileExistsError`` if ``path`` exists and ``overwrite`` is False.
    """
    path = pathlib.Path(path)
    if isinstance(scenes, SceneMetadata):
        scenes = [scenes]
    payload = [s.to_dict() for s in scenes]
    return atomic_write_text(path, json.dumps(payload, indent=2) + "\n", overwrite=overwrite)
