"""A horizontal shift the reference cannot determine is refused up front (a DSM spanning a few of
REF's cells: the Ventoux crop's DSM on 90 m SRTM), ``vertical_only`` fits ``dz`` alone, a shift
running beyond what the overlap allows is stopped, and a fit that did not converge gives its
statistics before and after over the same cells."""

import math
import re
import warnings

import numpy as np
import pytest
from affine import Affine

from jaxgeo.cli import main
from jaxgeo.coreg import (
    CoregistrationError,
    CoregistrationWarning,
    NuthKaab,
    coregister,
    dh_stats,
    nuth_kaab,
    shift_heights,
)
from jaxgeo.io import read_dem
from tests.coreg.test_coregister import CELL_M, CRS, X0, Y0, shifted_pair, write_raster

SRTM = "ventoux/dem/N44E005_srtm90.tif"


def smooth(east_m, north_m):
    """Gentle hills (wavelengths of 250-600 m): bilinear between 30 m posts within 0.07 m."""
    u, v = east_m - X0, north_m - Y0
    return 300.0 + 0.05 * u + 20.0 * np.sin(u / 90.0) * np.cos(v / 60.0) + 8.0 * np.sin(v / 40.0)


def small_dsm_on_coarse_ref(folder, rows=60, cols=120, ref_cell=30.0, dz=5.0):
    """A 1 m DSM of ``cols`` x ``rows`` m (``smooth`` + ``dz``) and a REF of ``ref_cell`` m posts
    around it (``smooth`` at the posts)."""
    c, r = np.meshgrid(np.arange(cols), np.arange(rows))
    dsm = smooth(X0 + (c + 0.5) * CELL_M, Y0 - (r + 0.5) * CELL_M) + dz
    write_raster(folder / "small.tif", dsm)
    x0, y0, n = X0 - 2 * ref_cell, Y0 + 2 * ref_cell, int(max(rows, cols) / ref_cell) + 5
    c, r = np.meshgrid(np.arange(n), np.arange(n))
    ref = smooth(x0 + (c + 0.5) * ref_cell, y0 - (r + 0.5) * ref_cell)
    transform = Affine(ref_cell, 0, x0, 0, -ref_cell, y0)
    write_raster(folder / "coarse.tif", ref, transform=transform)
    return folder / "small.tif", folder / "coarse.tif"


def test_a_dsm_over_few_reference_cells_is_refused_and_vertical_only_fits_dz(tmp_path):
    dsm, ref = small_dsm_on_coarse_ref(tmp_path)
    with pytest.raises(CoregistrationError) as caught:
        coregister(dsm, ref, tmp_path / "out.tif")
    message = str(caught.value)
    for named in ("small.tif (1 x 1 m cells", "120 m east-west x 60 m north-south",
                  "spans only 4.0 x 2.0 cells of", "coarse.tif (30.0 x 30.0 m cells)",
                  ">= 10 in each direction", "a larger DSM, a finer reference, or "
                  "vertical_only"):  # fmt: skip
        assert named in message, message
    assert caught.value.settings == ("min_ref_cells", "vertical_only")
    assert not (tmp_path / "out.tif").exists()
    # the threshold is min_ref_cells: 2.5 refuses, 2 lets it on to the fit
    with pytest.raises(CoregistrationError, match="spans only 4.0 x 2.0"):
        coregister(dsm, ref, settings=NuthKaab(min_ref_cells=2.5))
    with warnings.catch_warnings(record=True):  # not converged here: 20 iterations swinging
        warnings.simplefilter("always", CoregistrationWarning)
        try:
            coregister(dsm, ref, settings=NuthKaab(min_ref_cells=2))
        except CoregistrationError as err:  # refused later (aspects, a run-away), not up front
            assert "spans only" not in str(err)
    # vertical only: dz alone, no iteration, converged, the statistics over the same cells
    result = coregister(dsm, ref, tmp_path / "out.tif", settings=NuthKaab(vertical_only=True))
    print("vertical only", result.shift_m, result.before, result.after)
    assert result.shift_m[:2] == (0.0, 0.0) and abs(result.shift_m[2] + 5.0) < 0.1
    assert result.converged and result.iterations == 0 and result.increments_m == ()
    assert result.before.cells == result.after.cells == 7200
    assert abs(result.before.median_m - 5.0) < 0.1 and abs(result.after.median_m) < 0.1


def test_the_cli_names_vertical_only_by_its_option(tmp_path, capsys):
    dsm, ref = small_dsm_on_coarse_ref(tmp_path)
    out = tmp_path / "out.tif"
    assert main(["coregister", str(dsm), str(ref), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxgeo coregister: error: ") and err.count("\n") == 1, err
    assert "spans only 4.0 x 2.0 cells" in err and "or --vertical-only" in err, err
    assert "vertical_only" not in err and not out.exists()
    assert main(["coregister", str(dsm), str(ref), "-o", str(out), "--vertical-only"]) == 0
    printed = capsys.readouterr().out
    dz = float(
        re.search(r"dx \+0\.000 m \(east\), dy \+0\.000 m \(north\), dz (\S+) m", printed)[1]
    )
    assert abs(dz + 5.0) < 0.1, printed
    assert "0 iterations, vertical only" in printed and out.is_file()


def test_ventoux_crop_sized_dsm_on_srtm_is_refused(real_data, tmp_path):
    """A 500 x 160 m DSM at 1 m (the Ventoux crops' DSM's size) made from SRTM itself, warped
    bilinearly onto UTM 31N and raised 7 m: 7.5 x 1.7 SRTM cells (66.6 x 92.6 m there). Before
    the check, the crops' own DSM ran 20 iterations, swinging by tens of metres, to a shift of
    (+5, -57) m (or away, to (53, -152) m, on the 1 m product of docs/dsm.md)."""
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.warp import reproject

    srtm = real_data / SRTM
    transform = Affine(1.0, 0, 675_100.0, 0, -1.0, 4_897_300.0)  # by the Ventoux crops
    z = np.full((160, 500), np.nan)
    with rasterio.open(srtm) as src:
        reproject(rasterio.band(src, 1), z, src_nodata=src.nodata, dst_transform=transform,
                  dst_crs=CRS, dst_nodata=np.nan, resampling=Resampling.bilinear)  # fmt: skip
    assert np.isfinite(z).all() and np.ptp(z) > 5.0  # sloping terrain, not a flat
    write_raster(tmp_path / "dsm.tif", z + 7.0, transform=transform, dtype="float64")
    with pytest.raises(CoregistrationError) as caught:
        coregister(tmp_path / "dsm.tif", srtm)
    message = str(caught.value)
    print(message)
    assert "500 m east-west x 160 m north-south" in message
    cells = [float(v) for v in message.split("spans only ")[1].split(" cells")[0].split(" x ")]
    assert 5.0 < cells[0] < 8.0 and 1.5 < cells[1] < 2.0, cells
    assert "N44E005_srtm90.tif (66." in message
    # vertical only: the 7 m, REF warped onto the DSM grid the same way (float32 heights)
    result = coregister(tmp_path / "dsm.tif", srtm, settings=NuthKaab(vertical_only=True))
    assert abs(result.shift_m[2] + 7.0) < 1e-3 and result.after.nmad_m < 1e-3
    # REF given as a DEM made ellipsoidal (EGM96): the same refusal
    geoid = real_data / "ventoux/dem/egm96_15_crop_lon3-8_lat42-47.gtx"
    with pytest.raises(CoregistrationError, match="spans only"):
        coregister(tmp_path / "dsm.tif", read_dem(srtm, geoid=str(geoid)))


def test_a_shift_beyond_the_overlap_is_stopped():
    dsm, ref = shifted_pair(seed=3)  # shifted by (3.2, -2.1) m: 3.8 m over 320 m
    step = (CELL_M, -CELL_M)
    with pytest.raises(CoregistrationError, match=r"ran to \(.*\) m after \d+ iterations?, beyond "
                       r"1\.6 m \(0\.005 x the 320 m shorter side") as caught:  # fmt: skip
        nuth_kaab(dsm, ref, step, settings=NuthKaab(max_shift_fraction=0.005, pyramid=()))
    assert caught.value.settings == ("max_shift_fraction", "vertical_only")
    result = nuth_kaab(dsm, ref, step, settings=NuthKaab(max_shift_fraction=0.05))
    assert math.hypot(3.2, -2.1) - 0.1 < math.hypot(*result.shift_m[:2]) < 16.0
    for bad in (0.0, 1.5):
        with pytest.raises(CoregistrationError, match="max_shift_fraction"):
            NuthKaab(max_shift_fraction=bad)
    with pytest.raises(CoregistrationError, match="min_ref_cells"):
        NuthKaab(min_ref_cells=0.5)


def test_not_converged_statistics_over_the_same_cells(tmp_path, capsys):
    """Stopped after one iteration: ``before`` and ``after`` over the cells with heights before
    and after the last shift (numpy's statistics over them), in the result and in the diff."""
    dsm, ref = shifted_pair(seed=4)
    dsm[:, :40] = np.nan  # cells the shift moves data onto or off
    step = (CELL_M, -CELL_M)
    settings = NuthKaab(max_iterations=1, tolerance_m=1e-6, pyramid=())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CoregistrationWarning)
        result = nuth_kaab(dsm, ref, step, settings=settings)
    assert not result.converged
    assert any("over the same" in str(w.message) for w in caught)
    moved = shift_heights(dsm, (*result.shift_m[:2], 0.0), step)
    common = np.isfinite(dsm) & np.isfinite(moved) & np.isfinite(ref)
    assert common.sum() < np.sum(np.isfinite(dsm) & np.isfinite(ref))  # cells were lost
    assert result.before == dh_stats((dsm - ref)[common])
    assert result.after.cells == result.before.cells == int(common.sum())
    # converged: as before, the stable cells with heights in both, each time
    done = nuth_kaab(dsm, ref, step)
    assert done.converged and done.before == dh_stats(dsm - ref)
    # the files and the CLI: the diff's statistics too, and the summary says so
    write_raster(tmp_path / "dsm.tif", dsm)
    write_raster(tmp_path / "ref.tif", ref)
    argv = ["coregister", str(tmp_path / "dsm.tif"), str(tmp_path / "ref.tif"), "-o",
            str(tmp_path / "out.tif"), "--diff", str(tmp_path / "dh.tif"), "--quiet",
            "--max-iterations", "1", "--tolerance", "1e-6"]  # fmt: skip
    assert main(argv) == 1
    printed = capsys.readouterr().out
    assert "NOT converged: the last shift's statistics, before and after it over the same" in (
        printed
    )
    lines = [line.split() for line in printed.splitlines() if line.startswith(("before", "after"))]
    assert len(lines) == 4 and len({line[1] for line in lines[:2]}) == 1, printed
    assert len({line[1] for line in lines[2:]}) == 1, printed
