"""Adjusted RPCs where GDAL, OTB and shareloc find them: OSSIM .geom and DIMAP v2 writers, the
placement beside a copy of the image or in its tags, GDAL reading back what was written."""

import pathlib
import warnings
import xml.etree.ElementTree as ET

import jax.numpy as jnp
import numpy as np
import pytest
import rasterio
from rasterio.transform import RPCTransformer

from jaxgeo.bundle._export import adjusted_rpc
from jaxgeo.io import read_rpc
from jaxgeo.io._rpc_geom_dimap import fit_direct_model, format_dimap_rpc, format_ossim_geom
from jaxgeo.io.internal import image_stem, plan_rpc_outputs, write_rpc_outputs
from jaxgeo.models import AffineBias, Biased, ShiftDriftBias
from jaxgeo.models.internal import monomials

REAL = pathlib.Path(__file__).parents[1] / "data" / "real"
STEM = "PHR1B_P_201709281038393_SEN_PRG_FC_178609-001"
DIMAP = REAL / f"RPC_{STEM}.XML"
IMAGE = REAL / f"{STEM}.tif"


@pytest.fixture(scope="module")
def rpc():
    return read_rpc(DIMAP)


@pytest.fixture(scope="module")
def cube(rpc):
    u = np.random.default_rng(1).uniform(-1, 1, (200, 3))
    return np.asarray(rpc.ground_offset) + 0.9 * u * np.asarray(rpc.ground_scale)


def _gdal_project(path, ground):
    """Project with the RPC GDAL itself finds for the raster at ``path``; our convention."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path) as src:
            rpcs = src.rpcs
    with RPCTransformer(rpcs) as t:
        rows, cols = t.rowcol(ground[:, 0], ground[:, 1], zs=ground[:, 2], op=lambda v: v)
    return np.stack([np.asarray(cols), np.asarray(rows)], axis=-1) - 0.5


def test_stems():
    for name in (f"{STEM}.tif", f"{STEM}_RPC.TXT", f"{STEM}_rpc.txt", f"{STEM}.RPB",
                 f"{STEM}.geom", f"RPC_{STEM}.XML"):  # fmt: skip
        assert image_stem(name) == STEM


def test_geom_and_dimap_read_back(rpc, cube, tmp_path):
    for name, text in (("a.geom", format_ossim_geom(rpc, "a")), ("RPC_a.XML", None)):
        if text is None:
            text = format_dimap_rpc(rpc)
        (tmp_path / name).write_text(text)
        back = read_rpc(tmp_path / name)
        np.testing.assert_allclose(
            np.asarray(back.project(cube)), np.asarray(rpc.project(cube)), atol=1e-9
        )
    # shareloc splits every .geom line on ": " (one key: value per line)
    lines = (tmp_path / "a.geom").read_text().splitlines()
    assert all(len(line.split(": ")) == 2 for line in lines)


def test_dimap_direct_model_matches_the_vendors(rpc):
    """Our fitted image -> ground model reproduces Airbus's own <Direct_Model> (which fixes the
    variable order and the lon=SAMP / lat=LINE naming shareloc reads)."""
    num, den, err = fit_direct_model(rpc)
    assert err < 1e-7  # degrees, ~1 cm
    d = ET.parse(DIMAP).getroot().find(".//Direct_Model")
    vendor = {
        (s, k): np.array([float(d.find(f"{s}_{k}_COEFF_{i}").text) for i in range(1, 21)])
        for s in ("SAMP", "LINE")
        for k in ("NUM", "DEN")
    }
    m = np.asarray(monomials(jnp.asarray(np.random.default_rng(2).uniform(-1, 1, (300, 3)))))
    for row, s in enumerate(("SAMP", "LINE")):
        theirs = (m @ vendor[s, "NUM"]) / (m @ vendor[s, "DEN"])
        ours = (m @ num[row]) / (m @ den[row])
        assert np.abs(theirs - ours).max() * float(rpc.ground_scale[row]) < 1e-7


@pytest.fixture(scope="module")
def affine_refit(rpc):
    model = Biased(rpc, AffineBias((2.5, -1.75), ((3e-5, -1e-5), (2e-5, 4e-5))))
    return model, adjusted_rpc(model, None)  # domain: the wrapped RPC's validity cube


@pytest.mark.parametrize("fmt", ["txt", "rpb"])
def test_refit_rpc_beside_a_copy_read_by_gdal(affine_refit, cube, tmp_path, fmt):
    """A drift/affine bias cannot be folded: the refitted RPC, written beside a copy of the
    image and read back by GDAL (the sidecar GDAL finds for the copy), projects like the
    adjusted model to < 0.01 px."""
    model, (refit, err, how) = affine_refit
    assert how == "refit" and err < 0.01
    plan = plan_rpc_outputs("left", IMAGE, tmp_path, fmt, copy_image=True)
    written = write_rpc_outputs(refit, plan)["written"]
    assert {p.name for p in written} == {f"{STEM}.tif", f"{STEM}_RPC.TXT" if fmt == "txt"
                                         else f"{STEM}.RPB"}  # fmt: skip
    gdal = _gdal_project(tmp_path / f"{STEM}.tif", cube)
    assert np.abs(gdal - np.asarray(model.project(cube))).max() < 0.01
    with pytest.raises(FileExistsError):
        write_rpc_outputs(refit, plan)


def test_exact_fold_into_geotiff_tags(rpc, cube, tmp_path):
    model = Biased(rpc, ShiftDriftBias((1.5, -0.5), (0.0, 0.0)))
    folded, err, how = adjusted_rpc(model, None)
    assert how == "exact" and err == 0.0
    plan = plan_rpc_outputs("left", IMAGE, tmp_path, write_into=True)
    write_rpc_outputs(folded, plan)
    gdal = _gdal_project(tmp_path / IMAGE.name, cube)
    assert np.abs(gdal - np.asarray(model.project(cube))).max() < 1e-6
    assert read_rpc(IMAGE).image_offset[0] == rpc.image_offset[0]  # the input is untouched


def test_placement_errors(tmp_path):
    lone = tmp_path / DIMAP.name  # an RPC file with no image beside it
    lone.write_bytes(DIMAP.read_bytes())
    with pytest.raises(ValueError, match="no image raster found"):
        plan_rpc_outputs("left", lone, tmp_path / "out", copy_image=True)
    assert plan_rpc_outputs("left", DIMAP, tmp_path, copy_image=True).image == IMAGE
    with pytest.raises(ValueError, match="unknown RPC format"):
        plan_rpc_outputs("left", IMAGE, tmp_path, "json")
