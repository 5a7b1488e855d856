"""The chain a user runs: ``jaxgeo dsm`` on a simulated pair, then that DSM as ``jaxgeo ortho
--dem`` with ``--dem-fill`` of a coarser orthometric DEM (an SRTM stand-in made from the scene's
truth: lon/lat cells of ~10 m, heights above EGM96). One test of about a minute and a half: a
simulated scene, a DSM and five orthoimages, the only way to show that the products compose."""

import json

import numpy as np
import pytest
import rasterio
from affine import Affine
from rasterio.warp import Resampling, reproject, transform_bounds

from jaxgeo.cli import main
from jaxgeo.io._geoid import read_geoid


def _srtm_like(truth_path, out, step_deg=1e-4, pad_deg=2e-3):
    """The truth DSM averaged onto lon/lat cells, voids given their nearest height (SRTM covers
    everything), minus the EGM96 undulation: orthometric heights."""
    from scipy import ndimage

    with rasterio.open(truth_path) as src:
        z, t, crs = src.read(1).astype(float), src.transform, src.crs
        w, s, e, n = transform_bounds(crs, "EPSG:4326", *src.bounds)
    w, s, e, n = w - pad_deg, s - pad_deg, e + pad_deg, n + pad_deg
    cols, rows = int((e - w) / step_deg), int((n - s) / step_deg)
    dst_t = Affine(step_deg, 0, w, 0, -step_deg, n)
    out_z = np.full((rows, cols), np.nan)
    reproject(z, out_z, src_transform=t, src_crs=crs, src_nodata=np.nan, dst_transform=dst_t,
              dst_crs="EPSG:4326", dst_nodata=np.nan, resampling=Resampling.average)  # fmt: skip
    nearest = ndimage.distance_transform_edt(~np.isfinite(out_z), return_distances=False,
                                             return_indices=True)  # fmt: skip
    out_z = out_z[tuple(nearest)]
    cc, rr = np.meshgrid(np.arange(cols) + 0.5, np.arange(rows) + 0.5)
    out_z -= read_geoid("egm96")(w + cc * step_deg, n - rr * step_deg)
    profile = dict(driver="GTiff", width=cols, height=rows, count=1, dtype="float32",
                   crs="EPSG:4326", transform=dst_t)  # fmt: skip
    with rasterio.open(out, "w", **profile) as dst:
        dst.write(out_z.astype("float32"), 1)
    return out


def _ortho(capsys, image, out, *args):
    code = main(["ortho", str(image), "-o", str(out), "--quiet", "--json", *map(str, args)])
    captured = capsys.readouterr()
    report = json.loads(captured.out.strip().splitlines()[-1]) if code == 0 else None
    return code, report, captured.err


def test_a_dsm_with_a_fill_is_the_next_dem(tmp_path, capsys):
    scene, dsm = tmp_path / "scene", tmp_path / "dsm.tif"
    assert main(["simulate", "stereo-scene", "--size", "240", "--exact-rpc", "--seed", "1",
                 "-o", str(scene), "--quiet"]) == 0  # fmt: skip
    left = scene / "left.tif"
    assert main(["dsm", str(left), str(scene / "right.tif"), "--roi", "70", "70", "100", "100",
                 "-o", str(dsm), "--quiet"]) == 0  # fmt: skip
    capsys.readouterr()
    srtm = _srtm_like(scene / "truth_dsm.tif", tmp_path / "srtm_egm96.tif")
    with rasterio.open(dsm) as src:  # five bands: the height band is found by its name
        assert src.count == 5 and src.crs.to_epsg() == 32631
        bounds = tuple(src.bounds)
        dsm_valid = np.isfinite(src.read(1)).mean()
    assert 0.2 < dsm_valid < 0.9  # holes and corners outside the ROI's footprint

    # the whole image on the DSM alone: refused, the DSM covers a part of its footprint
    code, _, err = _ortho(capsys, left, tmp_path / "o.tif", "--dem", dsm)
    assert code == 2 and "dsm.tif: the DEM covers only" in err and "--dem-fill" in err

    grid = ["--crs", "EPSG:32631", "--bounds", *bounds, "--res", "0.7"]  # the DSM's box
    fill = ["--dem-fill", srtm, "--dem-fill-geoid", "egm96"]
    runs = {
        "truth": ["--dem", scene / "truth_dsm.tif", *grid],
        "dsm": ["--dem", dsm, *grid],  # enough: it covers the bounds
        "dsm+fill": ["--dem", dsm, *fill, *grid],
        "geoid forgotten": ["--dem", dsm, "--dem-fill", srtm, *grid],
    }
    valid, data, errs = {}, {}, {}
    for name, args in runs.items():
        out = tmp_path / f"ortho_{name.replace(' ', '_').replace('+', '_')}.tif"
        code, report, errs[name] = _ortho(capsys, left, out, *args)
        assert code == 0, errs[name]
        valid[name] = report["valid_fraction"]
        with rasterio.open(out) as src:
            data[name] = src.read(1, masked=True).astype(float)  # uint16: no wrap-around
    # a DEM that covers the --like grid is enough too (a 0.7 m grid inside the DSM's box)
    w, s_, e, n = bounds
    inner = rasterio.Affine(0.7, 0.0, w + 0.2 * (e - w), 0.0, -0.7, n - 0.2 * (n - s_))
    with rasterio.open(tmp_path / "grid.tif", "w", driver="GTiff", width=int(0.6 * (e - w) / 0.7),
                       height=int(0.6 * (n - s_) / 0.7), count=1, dtype="uint8",
                       crs="EPSG:32631", transform=inner) as g:  # fmt: skip
        g.write(np.zeros((1, g.height, g.width), np.uint8))
    code, _, err_like = _ortho(capsys, left, tmp_path / "like.tif", "--dem", dsm,
                               "--like", tmp_path / "grid.tif")  # fmt: skip
    assert code == 0, err_like  # refused before: the DSM does not cover the image's footprint
    with capsys.disabled():  # the figures a reader wants
        print("\nvalid fraction of the ortho over the DSM's box:", valid)
    assert valid["dsm+fill"] == pytest.approx(1.0) and valid["dsm"] < 0.9
    assert valid["dsm+fill"] > valid["dsm"] + 0.1
    # the rule: the fill's orthometric heights made ellipsoidal with EGM96 (~50 m here) before
    # they fill the ellipsoidal DSM; forgetting --dem-fill-geoid is warned and shows
    assert "its heights are +5" in errs["geoid forgotten"] and "--dem-fill" not in errs["dsm"]
    truth = data["truth"]
    holes = np.ma.getmaskarray(data["dsm"]) & ~np.ma.getmaskarray(truth)  # filled pixels only
    assert holes.mean() > 0.1
    scale = float(truth[holes].std())
    err = {k: float(np.abs(data[k][holes] - truth[holes]).mean()) / scale
           for k in ("dsm+fill", "geoid forgotten")}  # fmt: skip
    with capsys.disabled():
        print("mean |ortho - truth ortho| / std in the filled pixels:", err)
    assert err["dsm+fill"] < 0.5 * err["geoid forgotten"]

    # beyond the DSM: the whole image on the DSM with its fill
    code, report, _ = _ortho(capsys, left, tmp_path / "whole.tif", "--dem", dsm, *fill)
    code_s, report_s, _ = _ortho(capsys, left, tmp_path / "srtm.tif", "--dem", srtm,
                                 "--geoid", "egm96")  # fmt: skip
    assert code == 0 and code_s == 0
    with capsys.disabled():
        print("whole image valid fraction: dsm+fill", report["valid_fraction"], "srtm alone",
              report_s["valid_fraction"])  # fmt: skip
    assert report["valid_fraction"] == pytest.approx(report_s["valid_fraction"], abs=0.02)
