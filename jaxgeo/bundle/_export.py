"""Writing an adjustment: adjusted models (JSON and RPC files), points, residuals, report.

Pixel frames (docs/conventions.md, "Pixel frames of crops"): the adjustment works in the
pixels of each raster given (a crop's origin folded into its model when it was opened). Every
adjusted model written as a file of its own (``adjusted_models.json``, the RPC files in the
output folder, ``<image>_jitter.csv``) is moved back to the frame of the model the image was
given with (:func:`~._models_json.framed_models`; the full product for a crop with its
product's model), so that a reader applies the crop's origin exactly once, as for the input
model. An RPC beside a copy of the raster or in its tags (``--copy-images``, ``--write-into``)
is in that raster's own pixels: GDAL's rule for a raster's own RPC. The adjusted parameters,
their sigmas and covariance (``adjusted_models.json``, the reports) are the adjustment's: in
the pixels of the rasters.

Nothing the user gave is overwritten: every path is checked against the inputs and against
existing files before anything is written, and each file is written atomically.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import json
import os
import pathlib
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

import numpy as np

from ..io.internal import (
    atomic_output,
    format_rpc_txt,
    image_stem,
    plan_rpc_outputs,
    sidecar_name,
    write_bytes,
    write_csv,
    write_rpc_outputs,
)
from ..models import RPC, AffineBias, Biased, JitterBias, fit_rpc
from ._models_json import delivered_rpcs, framed_models, models_json
from ._report import format_reports


def adjusted_rpc(model: Any, domain: RPC | None = None) -> tuple[RPC, float, str]:
    """An RPC equivalent to an adjusted model: ``(rpc, max_error_px, how)``.

    The model's own :meth:`~jaxgeo.models.AbstractSensorModel.exact_rpc` when it has one (an
    RPC, or an RPC with a shift folded into its image offsets: ``how = "exact"``). Otherwise
    (a bias with drift or affine terms mixes the sample and line rational functions, whose
    denominators differ) the RPC is re-fitted to the model over the validity cube and image of
    ``domain`` (the delivered RPC; ``how = "refit"``, ``max_error_px`` the maximum error on the
    independent check grid). A jitter's spline is left out: it is :func:`jitter_grid`'s.
    Raises ``TypeError`` when neither is possible.
    """
    if isinstance(model, Biased) and isinstance(model.bias, JitterBias):  # the grid holds s(y)
        model = Biased(model.model, AffineBias(model.bias.shift_px, model.bias.matrix))
    exact = model.exact_rpc()
    if exact is not None:
        return exact, 0.0, "exact"
    if domain is None:  # Biased(RPC, drift/affine): its RPC
        domain = model.base_rpc()
    if domain is None:
        raise TypeError(f"no RPC form for a {type(model).__name__} model")
    off, scale = np.asarray(domain.image_offset), np.asarray(domain.image_scale)
    n_cols, n_rows = (int(round(o + s)) + 1 for o, s in zip(off, scale, strict=True))
    go, gs = np.asarray(domain.ground_offset), np.asarray(domain.ground_scale)
    refit, report = fit_rpc(model, n_cols, n_rows, (go[2] - gs[2], go[2] + gs[2]))
    return refit, float(report.check_max_px), "refit"


def jitter_grid(model: Any) -> str | None:
    """The line-dependent correction of a :class:`~jaxgeo.models.JitterBias` as CSV text (None
    for any other model): ``line,dx_px,dy_px`` every quarter knot spacing over the image's
    lines, such that ``image = RPC(ground) + (dx, dy)`` where RPC is the adjusted RPC written
    beside it (:func:`adjusted_rpc`: the affine part) and ``(dx, dy)`` is read (linearly
    interpolated) at the RPC's line. The error of reading it at the RPC's line instead of the
    image's is the correction's slope times ``dy`` (1e-2 px for 1.5 px at a 1000-line period)."""
    if not (isinstance(model, Biased) and isinstance(model.bias, JitterBias)):
        return None
    bias = model.bias
    n = bias.knots_px.shape[0]
    last = bias.line0 + (n - 3) * bias.knot_lines
    lines = np.arange(bias.line0, last + bias.knot_lines / 8, bias.knot_lines / 4)
    s = np.asarray(bias.offsets(lines))
    # (I + M) image + a0 + s(y) = RPC model pixel  =>  image = affine part - (I + M)^-1 s(y)
    corr = -np.linalg.solve(np.eye(2) + np.asarray(bias.matrix), s.T).T
    return _csv(["line", "dx_px", "dy_px"], [[_r(y), _r(c[0]), _r(c[1])] for y, c in
                                             zip(lines, corr, strict=True)])  # fmt: skip


def _csv(header: list[str], rows: Iterable[Iterable[Any]]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


class _Table(NamedTuple):
    """A CSV output: its header and rows, formed as they are written (:func:`jaxgeo.io.write_csv`:
    100 000 points and 200 000 residuals are never held as strings)."""

    header: list[str]
    rows: Iterable[Iterable[Any]]


def _fill(tmp: pathlib.Path, content: str | _Table) -> None:
    if isinstance(content, _Table):
        write_csv(tmp, content.header, content.rows)
    else:
        write_bytes(tmp, content.encode("utf-8"))


def _r(v: float) -> str:
    return repr(float(v))


FIXED_OUTPUTS = (
    "adjusted_models.json", "ground_adjusted.csv", "residuals.csv", "report.json", "report.txt",
)  # fmt: skip


def rpc_plans(
    images: Mapping[str, str | os.PathLike],
    out: pathlib.Path,
    rpc_format: str = "txt",
    copy_images: bool = False,
    write_into: bool = False,
) -> dict[str, Any]:
    """Image name -> where its adjusted RPC goes (:func:`~jaxgeo.io.plan_rpc_outputs`;
    two images of the same stem are written under their image names)."""
    stems = {name: image_stem(path) for name, path in images.items()}
    clash = {s for s in stems.values() if list(stems.values()).count(s) > 1}
    return {
        name: plan_rpc_outputs(
            name,
            images[name],
            out,
            rpc_format,
            stem=name if stems[name] in clash else None,
            copy_image=copy_images,
            write_into=write_into,
        )  # fmt: skip
        for name in images
    }


def output_paths(
    out_dir: str | os.PathLike,
    images: Mapping[str, str | os.PathLike] | Iterable[str],
    rpc_format: str = "txt",
    copy_images: bool = False,
    write_into: bool = False,
) -> list[pathlib.Path]:
    """Every file :func:`write_outputs` may write: the fixed outputs and, per image, its RPC
    (and image copy) as planned from ``images`` (name -> file), or ``NAME_adjusted_RPC.TXT``
    when only names are given, and the jitter grids a jitter bias writes."""
    out = pathlib.Path(out_dir)
    paths = [out / n for n in FIXED_OUTPUTS]
    if isinstance(images, Mapping):
        plans = rpc_plans(images, out, rpc_format, copy_images, write_into)
        paths += [p for plan in plans.values() for p in plan.targets]
    else:
        paths += [out / f"{n}_adjusted_RPC.TXT" for n in images]
    return paths + [out / f"{n}_jitter.csv" for n in images]  # with a jitter bias


SIDECAR_FORMATS = ("txt", "rpb", "geom", "dimap")


def sidecar_clash(
    targets: Iterable[str | os.PathLike], inputs: Iterable[str | os.PathLike]
) -> tuple[pathlib.Path, pathlib.Path] | None:
    """``(target, raster)`` when an output would be an RPC sidecar of an input raster (its
    ``<stem>_RPC.TXT``, ``.RPB``, ``.geom`` or ``RPC_<stem>.XML`` beside it): GDAL, OTB and
    shareloc would then read it as that input's model, an input changed in effect."""
    side = {}
    for inp in map(pathlib.Path, inputs):
        if inp.suffix.lower() in (".tif", ".tiff", ".ntf", ".nitf", ".jp2", ".img", ".vrt"):
            for fmt in SIDECAR_FORMATS:
                name = sidecar_name(inp.stem, fmt)
                side[str(inp.resolve().with_name(name)).lower()] = inp
    for target in map(pathlib.Path, targets):
        raster = side.get(str(target.resolve()).lower())
        if raster is not None:
            return target, raster
    return None


def probe_folder(out: pathlib.Path) -> None:
    """``out`` can be created (or written, when it exists): a folder is made (and removed) in
    it or its nearest existing parent (``os.access`` says yes to root everywhere, even in
    /proc). Raises ``PermissionError`` naming both."""
    import tempfile

    base = out
    while not base.exists() and base != base.parent:
        base = base.parent
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".jaxgeo-probe-", dir=base))
    except OSError as err:
        raise PermissionError(f"{out}: cannot be created ({base}: {err.strerror})") from None


def check_out_dir(
    out_dir: str | os.PathLike,
    images: Mapping[str, str | os.PathLike] | Iterable[str],
    inputs: Iterable[str | os.PathLike] = (),
    overwrite: bool = False,
    rpc_format: str = "txt",
    copy_images: bool = False,
    write_into: bool = False,
) -> None:
    """Before any computation: ``out_dir`` is (or can be created as) a writable folder, and no
    file :func:`write_outputs` will write (:func:`output_paths`, with the same ``images`` and
    options) is an input, an RPC sidecar of an input raster (:func:`sidecar_clash`) or (unless
    ``overwrite``) exists. Raises ``FileExistsError`` /
    ``PermissionError`` / ``NotADirectoryError`` naming the path, ``ValueError`` when an image
    to copy is not found."""
    out = pathlib.Path(out_dir)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: --out exists and is not a folder")
    base = out
    while not base.exists():
        base = base.parent if base.parent != base else base
        if base == base.parent:
            break
    if not os.access(base, os.W_OK | os.X_OK):
        raise PermissionError(f"{out}: cannot write there ({base} is not writable)")
    if not out.exists():
        probe_folder(out)
    if (copy_images or write_into) and isinstance(images, Mapping):
        _refuse_crop_copies(images)
    inputs = list(inputs)
    given = {pathlib.Path(p).resolve() for p in inputs}
    targets = output_paths(out, images, rpc_format, copy_images, write_into)
    clash = sidecar_clash(targets, inputs)
    if clash is not None:
        raise FileExistsError(
            f"{clash[0]}: refusing to write an RPC beside the input image {clash[1]}: tools "
            "would read it as that image's model (choose another --out)"
        )
    for target in targets:
        path = target.resolve()
        if path in given or any(_same_file(path, p) for p in inputs):  # a hard link too
            raise FileExistsError(f"{path}: refusing to write an adjusted file over an input")
        if path.is_dir():
            raise IsADirectoryError(f"{path}: is a folder where an output goes")
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path}: exists (choose another --out or pass --overwrite)")


def _same_file(a: pathlib.Path, b: str | os.PathLike) -> bool:
    try:
        return a.exists() and pathlib.Path(b).exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _refuse_crop_copies(images: Mapping[str, str | os.PathLike]) -> None:
    """A copy of a crop would carry its frame and an RPC already in the crop's pixels."""
    from ..io.internal import detect_rpc_format, pixel_frame

    for name, path in images.items():
        if detect_rpc_format(path) == "raster" and pixel_frame(path) != (0.0, 0.0):
            raise ValueError(
                f"--copy-images/--write-into: image {name!r} ({path}) is a crop whose "
                "geotransform puts it in its product's frame; a copy would carry that frame "
                "and an RPC already in the crop's pixels (read shifted by tools that apply "
                "the frame): write the RPC files only"
            )


@dataclasses.dataclass(frozen=True)
class RPCOutputs:
    """How :func:`write_outputs` writes the adjusted RPCs: ``images`` (image name -> the image
    or RPC file it was read from; ``None``: each RPC is ``NAME_adjusted_RPC.TXT``) places each
    where GDAL/OTB/shareloc find it for that image (:mod:`jaxgeo.io._rpc_place`:
    ``<image stem>_RPC.TXT`` / ``.RPB`` / ``.geom`` / ``RPC_<stem>.XML`` by ``rpc_format``,
    beside a copy of the image with ``copy_images``, or in the tags of a copy of the GeoTIFF
    with ``write_into``); ``rpc_files=False``: no RPC at all. ``origins``: image name -> the
    model pixel of the raster's first pixel (a crop's origin): the models written as files of
    their own are moved back by it to their input model's frame (module docstring); the RPCs
    beside a copy of the raster or in its tags stay in the raster's pixels."""

    images: Mapping[str, str | os.PathLike] | None = None
    rpc_format: str = "txt"
    copy_images: bool = False
    write_into: bool = False
    rpc_files: bool = True
    origins: Mapping[str, tuple[float, float]] | None = None


def write_outputs(
    out_dir: str | os.PathLike,
    result,
    report_text: str,
    report: dict[str, Any],
    inputs: Iterable[str | os.PathLike] = (),
    overwrite: bool = False,
    rpcs: RPCOutputs = RPCOutputs(),
) -> list[pathlib.Path]:
    """Write the adjustment into ``out_dir``; refuse to touch an input or (unless
    ``overwrite``) an existing file. Returns the paths written. The adjusted RPCs go where
    ``rpcs`` says (:class:`RPCOutputs`); an RPC is folded exactly where the bias allows, else
    refitted; the refit error is in ``report.txt`` and ``report.json``."""
    images, rpc_files = rpcs.images, rpcs.rpc_files
    origins = rpcs.origins or {}
    framed = framed_models(result, origins)  # every model written as a file of its own
    out = pathlib.Path(out_dir)
    files: dict[str, str | _Table] = {}
    notes = []
    placed = []
    if rpc_files and images is not None:
        placed, notes, report = _place_rpcs(result, out, rpcs, report)
    elif rpc_files:
        delivered = delivered_rpcs(result, origins)
        for name, model in framed.items():
            try:
                rpc, err, how = adjusted_rpc(model, delivered[name])
            except TypeError:
                continue
            files[f"{name}_adjusted_RPC.TXT"] = format_rpc_txt(rpc)
            notes.append(
                f"{name}_adjusted_RPC.TXT: {how}"
                + (f" (max error {err:.3g} px on the check grid)" if how == "refit" else "")
            )
    for name, model in framed.items():
        grid = jitter_grid(model)
        if grid is not None:
            files[f"{name}_jitter.csv"] = grid
            notes.append(
                f"{name}_jitter.csv: the jitter correction along the lines (image = RPC(ground) "
                "+ (dx, dy) at the RPC's line); the RPC holds the affine bias only"
            )
    if any(np.any(np.asarray(o) != 0) for o in origins.values()):
        notes.append(
            "pixel frames: adjusted_models.json, the RPC files and jitter grids are in the "
            "pixels of each image's input model (a crop's product: its geotransform or "
            "--image-origin applies to them as to that model); an RPC beside a copy of a raster "
            "or in its tags, in that raster's pixels"
        )
    files["adjusted_models.json"] = json.dumps(models_json(result, origins), indent=1) + "\n"
    files["ground_adjusted.csv"] = _Table(
        ["id", "lon", "lat", "h", "role", "sigma_e_m", "sigma_n_m", "sigma_h_m"],
        (
            [p, *(_r(v) for v in g), role, *(_r(v) for v in s)]
            for p, role, g, s in zip(
                result.point_ids,
                result.point_role,
                result.ground,
                result.ground_sigma_m,
                strict=True,
            )
        ),
    )
    files["residuals.csv"] = _Table(
        ["id", "image", "vx_px", "vy_px", "wx", "wy", "blunder"],
        (
            [p, img, _r(v[0]), _r(v[1]), _r(w[0]), _r(w[1]), int(b)]
            for p, img, v, w, b in zip(
                result.observation_ids,
                result.observation_images,
                result.residuals_px,
                result.standardized,
                result.blunders,
                strict=True,
            )
        ),
    )
    files["report.json"] = json.dumps(report, indent=1) + "\n"
    files["report.txt"] = report_text + ("\n\n" + "\n".join(notes) if notes else "") + "\n"
    targets = {n: (out / n).resolve() for n in files}
    inputs = list(inputs)
    given = {pathlib.Path(p).resolve() for p in inputs}
    planned = [*targets.values(), *(p for _, plan in placed for p in plan.targets)]
    clash = sidecar_clash(planned, inputs)
    if clash is not None:
        raise FileExistsError(
            f"{clash[0]}: refusing to write an RPC beside the input image {clash[1]}: tools "
            "would read it as that image's model (choose another --out)"
        )
    for path in [*targets.values(), *(p.resolve() for _, plan in placed for p in plan.targets)]:
        if path in given:
            raise FileExistsError(f"{path}: refusing to write an adjusted file over an input")
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path}: exists (choose another --out or pass --overwrite)")
    written = []
    # every file to its temporary first (the CSV tables take seconds at 100 000 points), the
    # RPCs, then all renamed at once: an interruption while they are formed leaves nothing
    with contextlib.ExitStack() as stack:
        for n, content in files.items():
            _fill(stack.enter_context(atomic_output(targets[n], overwrite)), content)
        for rpc, plan in placed:
            written += write_rpc_outputs(rpc, plan, overwrite=overwrite)["written"]
    return written + [targets[n] for n in files]


def _place_rpcs(result, out, rpcs: RPCOutputs, report):
    """Plan every image's adjusted RPC (exact or refitted) before anything is written: in the
    frame of the image's input model, or in the raster's pixels beside a copy of it."""
    origins = rpcs.origins or {}
    framed, delivered = framed_models(result, origins), delivered_rpcs(result, origins)
    own, own_delivered = result.models, delivered_rpcs(result)
    plans = rpc_plans({n: rpcs.images[n] for n in result.models}, out, rpcs.rpc_format,
                      rpcs.copy_images, rpcs.write_into)  # fmt: skip
    placed, notes, info = [], [], {}
    for name in result.models:
        plan = plans[name]
        beside = plan.image_copy is not None or plan.write_into  # the raster's own RPC
        model = own[name] if beside else framed[name]
        try:
            rpc, err, how = adjusted_rpc(model, (own_delivered if beside else delivered)[name])
        except TypeError as e:
            notes.append(f"{name}: no RPC written ({e})")
            info[name] = {"how": "none", "reason": str(e)}
            continue
        placed.append((rpc, plan))
        where = ", ".join(p.name for p in plan.targets)
        notes.append(f"{name} -> {where}: {how}" + (
            f" (max error {err:.3g} px on the check grid)" if how == "refit" else ""))  # fmt: skip
        info[name] = {"how": how, "max_error_px": err, "files": [str(p) for p in plan.targets]}
    return placed, notes, {**report, "rpc_files": info}


__all__ = [
    "adjusted_rpc",
    "check_out_dir",
    "format_reports",
    "jitter_grid",
    "output_paths",
    "rpc_plans",
    "sidecar_clash",
    "write_outputs",
]
