"""A sensor image: a raster, its sensor model and its pixel frame.

Every command and the API take an image the same way. The raster (any file GDAL reads) is optional
where only its model is needed; the model is the raster's own RPC (GeoTIFF tags, ``.RPB`` or
``_RPC.TXT`` sidecar) unless a model file is given. The **pixel frame** relates the raster's pixels
to the model's (docs/conventions.md, "Pixel frames of crops"):

- a model file given separately (any RPC file :func:`~jaxgeo.io.read_rpc` reads, or the
  ``adjusted_models.json`` of ``jaxgeo adjust``: the entry of the image's name) is in the frame
  of the product it was made for; a crop of that product carries a pixel-space geotransform (a
  translation with unit scale and no CRS; shareloc's and CARS' convention), read as the model
  pixel ``origin = (col, row)`` of the raster's first pixel. ``origin=`` overrides it (the CLI's
  ``--image-origin``); a conflict with the file's own frame is an error;
- the raster's own model (its RPC tags or sidecar) is in the raster's own pixels, as GDAL reads
  it: a geotransform's origin is not applied to it (``origin=`` still is).

:attr:`SensorImage.model` works in the raster's pixels (the origin folded in by :func:`reframed`:
an RPC's image offsets are shifted, a bias re-expressed, any other model wrapped in a
:class:`~jaxgeo.models.ShiftBias`), so every stage downstream (matching, rectification,
orthorectification, adjustment) is frame-agnostic, and every pixel coordinate jaxgeo reads or
writes for an image is a pixel of the raster the user gave. A model jaxgeo writes as a file of its
own is moved back to its input model's frame (``reframed(model, origin)``), so that the origin is
applied exactly once by every reader.
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import JaxgeoError
from ..models import RPC, AbstractSensorModel, Biased, ShiftBias
from ._adjusted import is_adjusted_models, read_adjusted_model
from ._raster import open_raster
from ._remote import RemotePath, as_path, is_remote
from ._rpc_accuracy import RPCAccuracy


class ImageError(JaxgeoError, ValueError):
    """An image that cannot be used as given (no model, a conflicting pixel frame, unreadable)."""


@dataclass(frozen=True)
class SensorImage:
    """An image: ``name`` (the raster's or model's file stem), ``model`` in the raster's pixel
    frame, ``origin`` (model pixel of the raster's pixel (0, 0); ``(0, 0)`` without a frame),
    ``path`` of the raster (``None`` when only a model was given), ``size`` ``(width, height)`` px
    (``None`` without a raster), ``model_path`` (where the model came from), ``source_model``
    (the model in its own frame) and ``vendor_accuracy`` (the RPC's stated ``ERR_BIAS`` /
    ``ERR_RAND``, :class:`~jaxgeo.io.RPCAccuracy`; ``None`` for a model that is not a vendor's
    RPC file: an adjusted model, a model object)."""

    name: str
    model: AbstractSensorModel
    origin: tuple[float, float]
    path: pathlib.Path | RemotePath | None
    size: tuple[int, int] | None
    model_path: pathlib.Path | RemotePath | None
    source_model: AbstractSensorModel
    vendor_accuracy: RPCAccuracy | None = None

    @property
    def inputs(self) -> tuple[pathlib.Path | RemotePath, ...]:
        """The files this image was read from (outputs must never be one of them)."""
        return tuple(p for p in (self.path, self.model_path) if p is not None)

    def domain(self) -> tuple[float, float, float, float]:
        """``(x_min, y_min, x_max, y_max)`` px in the raster frame of valid pixel coordinates:
        the raster's extent when there is one (pixel centres, +-0.5 px for the edges), else the
        RPC's image domain (offset +- scale), else unbounded."""
        if self.size is not None:
            w, h = self.size
            return (-0.5, -0.5, w - 0.5, h - 0.5)
        rpc = self.model.base_rpc()
        if rpc is None:
            return (-math.inf, -math.inf, math.inf, math.inf)
        off, scale = np.asarray(rpc.image_offset), np.abs(np.asarray(rpc.image_scale))
        lo, hi = off - scale, off + scale
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))

    def validity_heights(self) -> tuple[float, float] | None:
        """``(h_min, h_max)`` m of the model's validity cube (its RPC's height offset +- scale),
        ``None`` for a model without one."""
        rpc = self.model.base_rpc()
        if rpc is None:
            return None
        # numpy: indexing the jax arrays would be two eager programs, compiled in every process
        off = float(np.asarray(rpc.ground_offset)[2])
        scale = abs(float(np.asarray(rpc.ground_scale)[2]))
        return (off - scale, off + scale)

    def check_heights(self, h_min: float, h_max: float, source: str) -> str | None:
        """Warn (and return the message) when heights ``h_min..h_max`` from ``source`` (e.g. a
        DEM's file name) leave the model's validity range: the RPC extrapolates there, or the
        DEM holds another height reference than the model (geoid vs ellipsoid)."""
        valid = self.validity_heights()
        if valid is None or (h_min >= valid[0] and h_max <= valid[1]):
            return None
        message = (
            f"{source}: heights {h_min:.0f}..{h_max:.0f} m leave the validity range "
            f"{valid[0]:.0f}..{valid[1]:.0f} m of the model of image {self.name}: the model "
            "extrapolates there (check the DEM's height reference: ellipsoidal or geoid)"
        )
        warnings.warn(message, UserWarning, stacklevel=2)
        return message


def pixel_frame(path: str | os.PathLike) -> tuple[float, float]:
    """The model pixel ``(col, row)`` of a raster's first pixel read from its geotransform:
    ``(0, 0)`` for none (identity) or a map georeferencing (a CRS); the translation of a
    pixel-space geotransform (unit scale, no rotation, no CRS). Anything else is an
    :class:`ImageError` naming the file."""
    with open_raster(path) as src:
        t, crs = src.transform, src.crs
    if crs is not None:
        return (0.0, 0.0)
    if (t.a, t.b, t.d, t.e) == (1.0, 0.0, 0.0, 1.0):
        return (float(t.c), float(t.f))
    raise ImageError(
        f"{path}: its geotransform {tuple(t)[:6]} is neither a map georeferencing (no CRS) nor a "
        "pixel-space translation of a crop (unit scale); give the crop's origin with --image-origin"
    )


def reframed(model: AbstractSensorModel, offset: tuple[float, float]) -> AbstractSensorModel:
    """``model`` in the pixel frame whose pixels are the model's plus ``offset = (dx, dy)`` px:
    ``reframed(m, d).project(g) == m.project(g) + d`` (exact: no refit).

    Moving a crop's model (pixel (0, 0) at model pixel ``o``) back to its product's frame is
    ``reframed(m, o)``; the crop's model of a product's is ``reframed(m, -o)``. An RPC's image
    offsets move by ``d``; a :class:`~jaxgeo.models.Biased` model keeps its structure, the
    wrapped model moved by ``d`` and its bias re-expressed in the new pixels: for
    ``to_model(x) = x + a0 + M x [+ s(y)]`` (every bias of :mod:`jaxgeo.models`, the jitter's
    spline ``s`` included) ``a0' = a0 - M d`` and a jitter's first line ``line0 + dy``. Any
    other model is wrapped in a :class:`~jaxgeo.models.ShiftBias` of ``-d`` (one that already
    is: its shift changed, or dropped when it cancels)."""
    d = np.asarray(offset, dtype=float).reshape(2)
    if not np.any(d):
        return model
    if isinstance(model, RPC):
        import equinox as eqx

        from .._runtime.arrays import device_array

        # the sum on the host, copied to the device: jax's sum and ``jnp.asarray`` would each
        # be an eager program, compiled in every process
        moved = device_array(np.asarray(model.image_offset) + d)
        return eqx.tree_at(lambda m: m.image_offset, model, moved)
    if isinstance(model, Biased):
        inner, bias = model.model, model.bias
        if isinstance(bias, ShiftBias) and not isinstance(inner, RPC | Biased):
            shift = np.asarray(bias.shift_px) - d  # undo (or move) a frame shift of its own
            return inner if not np.any(shift) else Biased(inner, ShiftBias(shift))
        return Biased(reframed(inner, tuple(d)), moved_bias(bias, d))
    return Biased(model, ShiftBias(-d))


def moved_bias(bias, offset) -> Any:
    """``bias`` for pixels moved by ``offset`` (and the model's pixels moved alike, see
    :func:`reframed`): ``to_model'(x) = to_model(x - d) + d``. Raises ``TypeError`` for a bias
    of a kind it does not know."""
    from ..models import AffineBias, JitterBias, ShiftDriftBias

    d = np.asarray(offset, dtype=float).reshape(2)
    a0, m = (np.asarray(v, dtype=float) for v in bias.coefficients())
    shift = a0 - m @ d
    if isinstance(bias, ShiftBias):
        return ShiftBias(shift)
    if isinstance(bias, ShiftDriftBias):
        return ShiftDriftBias(shift, bias.drift)
    if isinstance(bias, AffineBias):
        return AffineBias(shift, bias.matrix)
    if isinstance(bias, JitterBias):
        n = bias.knots_px.shape[0]
        line0 = bias.line0 + float(d[1])
        return JitterBias((line0, line0 + (n - 3) * bias.knot_lines), bias.knot_lines,
                          bias.smoothness_px, shift, bias.matrix, bias.knots_px)  # fmt: skip
    raise TypeError(f"cannot move a {type(bias).__name__} to another pixel frame")


def _shifted(model: AbstractSensorModel, origin: tuple[float, float]) -> AbstractSensorModel:
    """``model`` in the frame whose pixel (0, 0) is the model's pixel ``origin``."""
    if origin == (0.0, 0.0):
        return model
    return reframed(model, (-origin[0], -origin[1]))


def open_image(
    path: str | os.PathLike | None = None,
    model: str | os.PathLike | AbstractSensorModel | None = None,
    origin: tuple[float, float] | None = None,
    name: str | None = None,
) -> SensorImage:
    """A :class:`SensorImage` from a raster ``path`` and/or a ``model`` (a file any RPC reader
    of :func:`~jaxgeo.io.read_rpc` knows, an ``adjusted_models.json`` of ``jaxgeo adjust`` (the
    adjusted model of image ``name``, its bias and jitter included), or a model object; default:
    the raster's own RPC). ``name``: the image's name (default: the raster's file stem, else the
    model file's).

    ``origin``: the model pixel of the raster's first pixel, overriding the raster's pixel-space
    geotransform (applied to a separate model only, see the module docstring); a different
    non-zero frame in the file is an :class:`ImageError`. Missing files raise
    ``FileNotFoundError``; a raster without a model an :class:`ImageError` naming it.

    ``path`` and ``model`` may be URLs (``https://``, ``s3://``, ``gs://``; a text model file by
    ``http(s)`` only): GDAL reads the raster by range requests, never whole; the name is the
    stem of the URL's last segment (query string dropped). See :mod:`jaxgeo.io._remote`.
    """
    from ._rpc_formats import read_rpc_with_accuracy

    if path is None and model is None:
        raise ImageError("an image needs a raster or a model")
    raster = as_path(path) if path is not None else None  # a URL stays one (no pathlib)
    size, frame = None, (0.0, 0.0)
    if raster is not None:
        if not is_remote(raster) and not raster.is_file():  # a URL's absence: GDAL's error
            raise FileNotFoundError(f"{raster}: no such image file")
        try:
            with open_raster(raster) as src:
                size = (int(src.width), int(src.height))
        except Exception as err:  # rasterio's RasterioIOError and GDAL's messages
            raise ImageError(f"{raster}: not a raster GDAL can read ({err})") from None
        if model is not None:  # the raster's own RPC is in its own pixels (GDAL's rule)
            frame = pixel_frame(raster)
    if origin is not None:
        origin = (float(origin[0]), float(origin[1]))
        if frame != (0.0, 0.0) and not np.allclose(frame, origin):
            raise ImageError(
                f"{raster}: --image-origin {origin[0]:g} {origin[1]:g} conflicts with the crop "
                f"origin {frame[0]:g} {frame[1]:g} in its geotransform"
            )
        frame = origin
    model_path, accuracy = None, None
    if isinstance(model, AbstractSensorModel):
        source_model = model
        stem = name or (raster or pathlib.Path("image")).stem
    else:
        model_path = as_path(model) if model is not None else raster
        stem = name or (raster or model_path).stem
        try:
            if model is not None and _is_adjusted(model_path):
                source_model = read_adjusted_model(model_path, stem)
            else:
                source_model, accuracy = read_rpc_with_accuracy(model_path)
        except FileNotFoundError:
            raise
        except ValueError as err:
            if model is None:
                raise ImageError(
                    f"{raster}: no sensor model in the image (RPC tags or an .RPB/_RPC.TXT "
                    f"sidecar) ({_first_line(err)}); give its model file"
                ) from None
            raise
    return SensorImage(
        name=stem,
        model=_shifted(source_model, frame),
        origin=frame,
        path=raster,
        size=size,
        model_path=model_path if model_path != raster else None,
        source_model=source_model,
        vendor_accuracy=accuracy,
    )


def _is_adjusted(path: pathlib.Path | RemotePath) -> bool:
    """Whether ``path`` is an ``adjusted_models.json`` (read whole only when it is JSON)."""
    from ._rpc_formats import detect_rpc_format

    if not path.is_file() or detect_rpc_format(path) != "json":
        return False
    try:
        root = json.loads(path.read_text(encoding="utf-8"))
    except ValueError:
        return False  # read_rpc names what is wrong
    return is_adjusted_models(root)


def _first_line(err: BaseException) -> str:
    return " ".join(str(err).split())[:200]


def outside_domain(image: SensorImage, xy: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
    """``(n,)`` bool: which of the ``(n, 2)`` raster-frame points ``xy`` lie outside the image's
    :meth:`~SensorImage.domain` by more than ``margin_px``."""
    x0, y0, x1, y1 = image.domain()
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return (
        (xy[:, 0] < x0 - margin_px)
        | (xy[:, 0] > x1 + margin_px)
        | (xy[:, 1] < y0 - margin_px)
        | (xy[:, 1] > y1 + margin_px)
        | ~np.all(np.isfinite(xy), axis=1)
    )
