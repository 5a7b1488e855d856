"""Put an adjusted RPC where users' tools find it for its image.

GDAL looks for an image's RPC beside the image: ``<stem>.RPB`` first, then ``<stem>_RPC.TXT``,
then the GeoTIFF's own RPC tags (checked with GDAL 3.x through rasterio: a sidecar wins over the
tags). OTB/OSSIM look for ``<stem>.geom``; shareloc/CARS take any of them or a DIMAP
``RPC_<stem>.XML``. :func:`plan_rpc_outputs` decides the destinations for one image:

- ``txt`` / ``rpb`` / ``geom`` / ``dimap`` (:data:`RPC_FORMATS`): the sidecar in ``out_dir``,
  named after the image's stem (taken from the image or the RPC file given for it:
  ``IMG.tif``, ``IMG_RPC.TXT``, ``IMG.RPB``, ``IMG.geom``, ``RPC_IMG.XML`` all give ``IMG``);
- ``copy_image``: also a copy of the image raster beside it (so GDAL opens the copy with the
  adjusted RPC; a copied GeoTIFF also gets it in its tags, so every reader agrees);
- ``write_into``: a copy of the GeoTIFF in ``out_dir`` with the adjusted RPC in its tags (the
  input is never modified).

:func:`write_rpc_outputs` writes them atomically and, where GDAL can open the result (a copied
image), checks that GDAL returns exactly the RPC written: an RPC GDAL would not use is an error,
never a silent leftover.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import re
import shutil

import numpy as np

from ..models import RPC
from ._atomic import atomic_output
from ._remote import as_path, is_remote
from ._rpc_formats import detect_rpc_format
from ._rpc_gdal import from_rasterio_rpc, write_geotiff_rpc
from ._rpc_geom_dimap import write_dimap_rpc, write_ossim_geom
from ._rpc_text import write_rpb, write_rpc_text

RPC_FORMATS = ("txt", "rpb", "geom", "dimap")
"""Sidecar formats: ``<stem>_RPC.TXT``, ``<stem>.RPB``, ``<stem>.geom``, ``RPC_<stem>.XML``."""
_RASTER_EXT = (".tif", ".tiff", ".TIF", ".TIFF", ".ntf", ".NTF", ".jp2", ".JP2")


def sidecar_name(stem: str, fmt: str) -> str:
    """File name of the ``fmt`` sidecar of the image ``stem``."""
    names = {"txt": f"{stem}_RPC.TXT", "rpb": f"{stem}.RPB", "geom": f"{stem}.geom",
             "dimap": f"RPC_{stem}.XML"}  # fmt: skip
    if fmt not in names:
        raise ValueError(f"unknown RPC format {fmt!r}; expected one of {', '.join(RPC_FORMATS)}")
    return names[fmt]


def image_stem(path: str | os.PathLike) -> str:
    """The image stem of an image or RPC file name (see the module docstring)."""
    name = as_path(path).name  # a URL: its last segment, query string dropped
    for pattern in (r"^(.+)_RPC\.TXT$", r"^RPC_(.+)\.XML$", r"^(.+)\.(?:RPB|geom)$"):
        m = re.match(pattern, name, re.IGNORECASE)
        if m:
            return m.group(1)
    return pathlib.Path(name).stem


def find_image(source: str | os.PathLike) -> pathlib.Path | None:
    """The image raster an RPC file belongs to: itself if it is a raster, else a raster with
    its stem beside it (DIMAP: ``IMG_<stem>``); ``None`` when there is none."""
    source = pathlib.Path(source)
    if source.exists() and detect_rpc_format(source) == "raster":
        return source
    stem = image_stem(source)
    for candidate_stem in (stem, f"IMG_{stem}"):
        for ext in _RASTER_EXT:
            candidate = source.with_name(candidate_stem + ext)
            if candidate.is_file():
                return candidate
    return None


@dataclasses.dataclass(frozen=True)
class RPCPlan:
    """Where one image's adjusted RPC goes: ``sidecar`` (or ``None`` with ``write_into``),
    ``image_copy`` (a copy of the image, ``None`` if none is made), ``fmt``."""

    name: str
    fmt: str
    sidecar: pathlib.Path | None
    image: pathlib.Path | None
    image_copy: pathlib.Path | None
    write_into: bool

    @property
    def targets(self) -> list[pathlib.Path]:
        return [p for p in (self.sidecar, self.image_copy) if p is not None]


def plan_rpc_outputs(
    name: str,
    source: str | os.PathLike,
    out_dir: str | os.PathLike,
    fmt: str = "txt",
    *,
    stem: str | None = None,
    copy_image: bool = False,
    write_into: bool = False,
) -> RPCPlan:
    """Destinations of the adjusted RPC of image ``name`` read from ``source`` (see the module
    docstring). Raises ``ValueError`` naming the image when a copy is asked for and no image
    raster is found, or ``write_into`` for an image that is not a GeoTIFF."""
    out = pathlib.Path(out_dir)
    stem = stem or image_stem(source)
    sidecar_name(stem, fmt)  # validates fmt
    if (copy_image or write_into) and is_remote(source):
        raise ValueError(
            f"image {name!r}: {source} is read by URL; --copy-images / --write-into copy the "
            "image (a download): copy it yourself, or write the RPC files only"
        )
    image = find_image(source) if (copy_image or write_into) else None
    if (copy_image or write_into) and image is None:
        raise ValueError(
            f"image {name!r}: no image raster found for {source} (looked for {stem}.tif/.ntf/"
            ".jp2 beside it); drop --copy-images / --write-into or give the image itself"
        )
    if write_into:
        if image.suffix.lower() not in (".tif", ".tiff"):
            raise ValueError(f"image {name!r}: --write-into needs a GeoTIFF, {image} is not one")
        return RPCPlan(name, fmt, None, image, out / image.name, True)
    copy = out / f"{stem}{image.suffix}" if image is not None else None
    return RPCPlan(name, fmt, out / sidecar_name(stem, fmt), image, copy, False)


def _gdal_rpc(path: pathlib.Path) -> RPC | None:
    import warnings

    import rasterio
    from rasterio.errors import NotGeoreferencedWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NotGeoreferencedWarning)
        with rasterio.open(path) as src:
            rpcs = src.rpcs
    return None if rpcs is None else from_rasterio_rpc(rpcs, str(path))


def _same_rpc(a: RPC, b: RPC) -> bool:
    pairs = zip(
        (a.num, a.den, a.ground_offset, a.ground_scale, a.image_offset, a.image_scale),
        (b.num, b.den, b.ground_offset, b.ground_scale, b.image_offset, b.image_scale),
        strict=True,
    )
    # GDAL's metadata text keeps ~15 significant digits
    return all(np.allclose(np.asarray(x), np.asarray(y), rtol=1e-12, atol=1e-15) for x, y in pairs)


def write_rpc_outputs(rpc: RPC, plan: RPCPlan, overwrite: bool = False) -> dict:
    """Write ``rpc`` as ``plan`` says; returns ``{"written": [paths], "direct_error_deg": ...}``
    (the DIMAP direct model's fit error, else ``None``). A copied image is checked with GDAL:
    ``ValueError`` if GDAL does not return ``rpc`` for it."""
    written: list[pathlib.Path] = []
    direct_err = None
    if plan.image_copy is not None:
        with atomic_output(plan.image_copy, overwrite, suffix=plan.image_copy.suffix) as tmp:
            shutil.copyfile(plan.image, tmp)
            # a copied GeoTIFF gets the adjusted RPC in its tags too, so that readers which
            # prefer the tags (jaxgeo.io.read_rpc) and those preferring sidecars (GDAL) agree
            if plan.write_into or plan.image.suffix.lower() in (".tif", ".tiff"):
                write_geotiff_rpc(rpc, tmp, update=True, overwrite=True)
        written.append(plan.image_copy)
    if plan.sidecar is not None:
        path = plan.sidecar
        if plan.fmt == "txt":
            write_rpc_text(rpc, path, overwrite=overwrite)
        elif plan.fmt == "rpb":
            write_rpb(rpc, path, overwrite=overwrite)
        elif plan.fmt == "geom":
            write_ossim_geom(rpc, path, overwrite=overwrite, image_id=plan.name)
        else:
            direct_err = write_dimap_rpc(rpc, path, overwrite=overwrite)[1]
        written.append(path)
    if plan.image_copy is not None and (plan.write_into or plan.fmt in ("txt", "rpb")):
        seen = _gdal_rpc(plan.image_copy)
        if seen is None or not _same_rpc(seen, rpc):
            raise ValueError(
                f"{plan.image_copy}: GDAL does not read the adjusted RPC just written for image "
                f"{plan.name!r} (another RPC source takes precedence); use --rpc-format rpb"
            )
    return {"written": written, "direct_error_deg": direct_err}


__all__ = [
    "RPC_FORMATS",
    "RPCPlan",
    "find_image",
    "image_stem",
    "plan_rpc_outputs",
    "sidecar_name",
    "write_rpc_outputs",
]
