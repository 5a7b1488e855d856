"""RPC writers for CNES / OTB tools: OSSIM ``.geom`` keyword lists and DIMAP v2 RPC XML.

Both are read back by :func:`jaxgeo.io.read_rpc` and by shareloc (so CARS, which uses it):

- ``.geom``: ``type: ossimRpcModel``, ``polynomial_format: B`` and the :data:`~._rpc_keys.STYLES`
  ``ossim_geom`` keys (``line_off`` ... ``samp_den_coeff_19``), one ``key: value`` per line (the
  layout shareloc's reader splits on ``": "``). Pixel convention ours (RPC standard).
- DIMAP v2 (``RPC_<image>.XML``, Pleiades / SPOT 6-7 layout): ``<Inverse_Model>`` (ground ->
  image, the RPC itself), ``<RFM_Validity>`` with the offsets counted from 1 (DIMAP's first
  pixel centre is (1, 1)), and a ``<Direct_Model>`` (image -> ground rational functions of
  normalised (col, row, h), lon as ``SAMP_*`` and lat as ``LINE_*``) which shareloc requires to
  be present. The direct model is fitted to the inverse one by least squares on an image grid
  (:func:`fit_direct_model`); its error is returned, its use is optional in every reader.
"""

from __future__ import annotations

import os
import pathlib
import xml.sax.saxutils as saxutils

import jax
import jax.numpy as jnp
import numpy as np

from ..models import RPC
from ..models.internal import monomials
from ._atomic import atomic_write_text
from ._rpc_common import fmt, vendor_values
from ._rpc_keys import N_TERMS, STYLES, vendor_items

_GEOM = STYLES["ossim_geom"]
_DIMAP = STYLES["dimap"]


def format_ossim_geom(rpc: RPC, image_id: str = "") -> str:
    """The OSSIM ``.geom`` keyword list of ``rpc`` (RPC00B, full float64 precision)."""
    lines = ["type: ossimRpcModel", "polynomial_format: B"]
    if image_id:
        lines.append(f"image_id: {image_id}")
    lines += ["bias_error: 0", "rand_error: 0"]  # unknown; OSSIM's own default
    for _, name, value in vendor_items(_GEOM, vendor_values(rpc)):
        lines.append(f"{name}: {fmt(value)}")
    return "\n".join(lines) + "\n"


def write_ossim_geom(
    rpc: RPC, path: str | os.PathLike, *, overwrite: bool = False, image_id: str = ""
) -> pathlib.Path:
    """Write ``rpc`` as an OSSIM/OTB ``.geom`` keyword list (atomic, never over an existing file
    unless ``overwrite``); name it ``<image>.geom`` for OTB to pick it up beside the image."""
    return atomic_write_text(path, format_ossim_geom(rpc, image_id), overwrite=overwrite)


@jax.jit
def _localize_grid(rpc: RPC, image, h):
    return rpc.localize(image, h)


def fit_direct_model(
    rpc: RPC, grid: tuple[int, int, int] = (21, 21, 7), iterations: int = 3
) -> tuple[np.ndarray, np.ndarray, float]:
    """Image -> ground rational functions of normalised ``(col, row, h)`` (RPC00B term order
    with L = col, P = row, H = h) fitted to ``rpc`` over its image range and height range.

    Returns ``(num, den, max_error_deg)``: ``num``, ``den`` ``(2, 20)`` (row 0 longitude,
    row 1 latitude, normalised by the RPC's ground offsets/scales) and the largest error in
    degrees on the grid. Linearised least squares reweighted by ``1 / Den`` (as
    :func:`jaxgeo.models.fit_rpc`).
    """
    i_off, i_scale = np.asarray(rpc.image_offset), np.asarray(rpc.image_scale)
    g_off, g_scale = np.asarray(rpc.ground_offset), np.asarray(rpc.ground_scale)
    nx, ny, nh = grid
    u = np.stack(
        np.meshgrid(np.linspace(-1, 1, nx), np.linspace(-1, 1, ny), np.linspace(-1, 1, nh)),
        axis=-1,
    ).reshape(-1, 3)
    image = i_off + u[:, :2] * i_scale
    h = g_off[2] + u[:, 2] * g_scale[2]
    ground = np.asarray(_localize_grid(rpc, jnp.asarray(image), jnp.asarray(h)))
    ok = np.all(np.isfinite(ground), axis=1)
    if ok.sum() < 3 * 39:
        raise ValueError("RPC localisation failed on most of its image grid; no direct model")
    m = np.asarray(monomials(jnp.asarray(u[ok])))
    num, den = np.zeros((2, N_TERMS)), np.zeros((2, N_TERMS))
    errors = []
    for k in range(2):
        v = (ground[ok, k] - g_off[k]) / g_scale[k]
        w = np.ones_like(v)
        for _ in range(iterations):
            a = np.concatenate([m, -v[:, None] * m[:, 1:]], axis=1) * w[:, None]
            coef = np.linalg.lstsq(a, v * w, rcond=None)[0]
            num[k], den[k] = coef[:N_TERMS], np.concatenate([[1.0], coef[N_TERMS:]])
            w = 1.0 / np.abs(m @ den[k])
        errors.append(np.max(np.abs((m @ num[k]) / (m @ den[k]) - v)) * g_scale[k])
    return num, den, float(max(errors))


def _tags(names_values, indent: str) -> list[str]:
    return [f"{indent}<{n}>{fmt(v)}</{n}>" for n, v in names_values]


def format_dimap_rpc(rpc: RPC, direct: tuple[np.ndarray, np.ndarray] | None = None) -> str:
    """The DIMAP v2 RPC XML of ``rpc``; ``direct`` ``(num, den)`` from :func:`fit_direct_model`
    (fitted here when ``None``)."""
    values = vendor_values(rpc)
    if direct is None:
        direct = fit_direct_model(rpc)[:2]
    d_num, d_den = direct
    ind = "        "
    inverse = [(name, value) for _, name, value in vendor_items(_DIMAP, values)]
    # the direct model under the same key names: SAMP_* give longitude, LINE_* latitude
    direct_items = []
    for stem, row in (("SAMP", 0), ("LINE", 1)):
        direct_items += [(f"{stem}_NUM_COEFF_{i + 1}", d_num[row, i]) for i in range(N_TERMS)]
        direct_items += [(f"{stem}_DEN_COEFF_{i + 1}", d_den[row, i]) for i in range(N_TERMS)]
    inverse_items = [(n, v) for n, v in inverse if "_COEFF_" in n]
    scalars = {n: v for n, v in inverse if "_COEFF_" not in n}
    scalars["SAMP_OFF"] += 1.0  # DIMAP: the first pixel centre is (1, 1)
    scalars["LINE_OFF"] += 1.0
    first_col = scalars["SAMP_OFF"] - scalars["SAMP_SCALE"]
    first_row = scalars["LINE_OFF"] - scalars["LINE_SCALE"]
    lon0, lat0 = values["lon_off"] - values["lon_scale"], values["lat_off"] - values["lat_scale"]
    lon1, lat1 = values["lon_off"] + values["lon_scale"], values["lat_off"] + values["lat_scale"]
    order = ("LONG_SCALE", "LONG_OFF", "LAT_SCALE", "LAT_OFF", "HEIGHT_SCALE", "HEIGHT_OFF",
             "SAMP_SCALE", "SAMP_OFF", "LINE_SCALE", "LINE_OFF")  # fmt: skip
    esc = saxutils.escape
    lines = [
        '<?xml version="1.0" encoding="UTF-8" standalone="no"?>',
        "<Dimap_Document>",
        "  <Metadata_Identification>",
        '    <METADATA_FORMAT version="2.15">DIMAP</METADATA_FORMAT>',
        "    <METADATA_PROFILE>PHR_SENSOR</METADATA_PROFILE>",
        "    <METADATA_SUBPROFILE>RPC</METADATA_SUBPROFILE>",
        "    <METADATA_LANGUAGE>en</METADATA_LANGUAGE>",
        "  </Metadata_Identification>",
        "  <Rational_Function_Model>",
        "    <Resource_Reference>",
        '      <RESOURCE_TITLE version="2.1">NITF</RESOURCE_TITLE>',
        f"      <RESOURCE_ID>{esc('RPC00B')}</RESOURCE_ID>",
        "    </Resource_Reference>",
        "    <Global_RFM>",
        "      <Direct_Model>",
        *_tags(direct_items, ind),
        f"{ind}<ERR_BIAS_X>0</ERR_BIAS_X>",
        f"{ind}<ERR_BIAS_Y>0</ERR_BIAS_Y>",
        "      </Direct_Model>",
        "      <Inverse_Model>",
        *_tags(inverse_items, ind),
        f"{ind}<ERR_BIAS_ROW>0</ERR_BIAS_ROW>",
        f"{ind}<ERR_BIAS_COL>0</ERR_BIAS_COL>",
        "      </Inverse_Model>",
        "      <RFM_Validity>",
        "        <Direct_Model_Validity_Domain>",
        *_tags(
            [
                ("FIRST_ROW", first_row),
                ("FIRST_COL", first_col),
                ("LAST_ROW", first_row + 2 * scalars["LINE_SCALE"]),
                ("LAST_COL", first_col + 2 * scalars["SAMP_SCALE"]),
            ],
            ind + "  ",
        ),  # fmt: skip
        "        </Direct_Model_Validity_Domain>",
        "        <Inverse_Model_Validity_Domain>",
        *_tags(
            [("FIRST_LON", lon0), ("FIRST_LAT", lat0), ("LAST_LON", lon1), ("LAST_LAT", lat1)],
            ind + "  ",
        ),  # fmt: skip
        "        </Inverse_Model_Validity_Domain>",
        *_tags([(n, scalars[n]) for n in order], ind),
        "      </RFM_Validity>",
        "    </Global_RFM>",
        "  </Rational_Function_Model>",
        "</Dimap_Document>",
    ]
    return "\n".join(lines) + "\n"


def write_dimap_rpc(
    rpc: RPC, path: str | os.PathLike, *, overwrite: bool = False
) -> tuple[pathlib.Path, float]:
    """Write ``rpc`` as a DIMAP v2 RPC XML (``RPC_<image>.XML``); returns the path and the
    largest error (degrees) of the fitted direct model. Atomic; never over an existing file
    unless ``overwrite``."""
    num, den, err = fit_direct_model(rpc)
    text = format_dimap_rpc(rpc, (num, den))
    return atomic_write_text(path, text, overwrite=overwrite), err


__all__ = [
    "fit_direct_model",
    "format_dimap_rpc",
    "format_ossim_geom",
    "write_dimap_rpc",
    "write_ossim_geom",
]
