"""The census semi-global matcher in JAX (``jaxgeo.stereo._sgm``): a known sub-pixel shift, the
left-right check at an occlusion, agreement with OpenCV's SGBM on rendered epipolar tiles, one
program per shape bucket, and ``jaxgeo dsm --matcher jax`` against the truth as ``opencv``."""

import contextlib
import io
import json

import numpy as np
import pytest

from jaxgeo.cli import main
from jaxgeo.stereo import DSMSettings, SGMSettings, sgm_disparity, stereo_pair
from jaxgeo.stereo._dense import default_matcher
from jaxgeo.stereo._matching import stretch_limits, to_uint8
from jaxgeo.stereo._sgm import (
    CHUNK_OVERLAP_ROWS,
    SGMMemoryError,
    _costs,
    _match,
    band_bytes,
    bucket,
    census_sgm,
    chunk_rows,
    memory_budget,
)

P1, P2 = SGMSettings().census_p1, SGMSettings().census_p2
PEN = (P1, P2)


def _texture(rows, cols, seed=0):
    import cv2

    noise = np.random.default_rng(seed).normal(size=(rows, cols)).astype(np.float32)
    return cv2.GaussianBlur(noise, (0, 0), 1.2)


def _shifted(left, d):
    """``right`` with ``right(x + d) = left(x)``: a band-limited shift in Fourier space."""
    k = np.fft.fftfreq(left.shape[1])
    spectrum = np.fft.fft(left, axis=1) * np.exp(-2j * np.pi * k * d)
    return np.real(np.fft.ifft(spectrum, axis=1)).astype(np.float32)


def _uint8(*images):
    lims = (min(float(i.min()) for i in images), max(float(i.max()) for i in images))
    return [to_uint8(i, lims) for i in images]


@pytest.mark.parametrize("d", [-7.0, -7.3, -6.6])
def test_a_shifted_image_gives_its_disparity(d):
    left = _texture(100, 180, seed=3)
    left8, right8 = _uint8(left, _shifted(left, d))
    disp = census_sgm(left8, right8, -12.0, 2.0, PEN)
    assert disp.dtype == np.float64 and disp.shape == left.shape
    core = disp[5:-5, 20:-20]  # (the Fourier shift wraps around at the ends)
    err = np.abs(core - d)
    assert np.isfinite(core).mean() > 0.95
    # the issue's bar is 0.2 px; measured: median 0.03 px, mean within 0.01 px
    assert np.nanmedian(err) < 0.1 and abs(np.nanmean(core) - d) < 0.05
    assert np.nanpercentile(err, 99) < 0.5


def test_the_left_right_check_removes_an_occluded_strip():
    """A strip 8 px nearer than its background (disparity -12 against -4): the background
    pixels just left of it in the left image are hidden by it in the right image."""
    rows, cols, d_bg, d_fg = 80, 200, -4, -12
    bg = _texture(rows, cols + 40, seed=5)
    fg = _texture(rows, 40, seed=6) * 1.5
    left = bg[:, 20 : 20 + cols].copy()
    left[:, 100:140] = fg
    right = bg[:, 20 - d_bg : 20 - d_bg + cols].copy()  # right(x + d_bg) = left(x)
    right[:, 100 + d_fg : 140 + d_fg] = fg
    left8, right8 = _uint8(left, right)
    occluded = (slice(5, -5), slice(100 + d_fg - d_bg + 1, 99))  # left columns 93..98
    checked = census_sgm(left8, right8, -16, 0, PEN, checks=(0, 1))
    unchecked = census_sgm(left8, right8, -16, 0, PEN, checks=(0, 10_000))
    assert np.isfinite(unchecked[occluded]).mean() > 0.95  # WTA picks something there
    assert np.isfinite(checked[occluded]).mean() < 0.2
    # visible pixels keep their disparities
    for cols_seen, d in ((slice(20, 85), d_bg), (slice(105, 135), d_fg), (slice(145, 180), d_bg)):
        seen = checked[5:-5, cols_seen]
        assert np.isfinite(seen).mean() > 0.9
        assert np.nanmedian(np.abs(seen - d)) < 0.3


def test_bands_of_one_bucket_share_one_program():
    left = _texture(70, 130, seed=1)
    left8, right8 = _uint8(left, _shifted(left, -3.0))
    assert bucket(70, 130, 15) == bucket(64 + 1, 128 + 1, 16) == (128, 192, 16)
    census_sgm(left8, right8, -10, 4, PEN)
    before = _costs._cache_size(), _match._cache_size()
    again = census_sgm(left8[:66, :129], right8[:66, :129], -9, 4, PEN)
    assert (_costs._cache_size(), _match._cache_size()) == before  # same bucket: no new trace
    assert again.shape == (66, 129)


def test_settings_and_the_default_matcher():
    import jax

    expected = "opencv" if jax.default_backend() == "cpu" else "jax"
    assert default_matcher() == expected and SGMSettings().matcher is None
    with pytest.raises(ValueError, match="matcher 'cuda'"):
        SGMSettings(matcher="cuda")
    with pytest.raises(ValueError, match="paths 6"):
        SGMSettings(paths=6)
    with pytest.raises(ValueError, match="one shape"):
        census_sgm(np.zeros((10, 10), np.uint8), np.zeros((10, 11), np.uint8), 0, 4, PEN)


def test_the_memory_a_band_needs_sets_its_chunks():
    """The budget in bytes sets the rows of a chunk: all of them when the band fits, else the
    most whose bucket (with the overlaps) fits; a refusal naming the setting and the CLI option
    when not even the smallest chunk fits -- before any work."""
    need = band_bytes(576, 1088, 128)
    assert 1.2e9 < need < 2.0e9  # ~20 bytes a voxel of the bucket
    assert band_bytes(576, 1088, 256) > 1.9 * need  # linear in the disparities
    assert chunk_rows(576, 1088, 128, need) == 576
    rows = chunk_rows(576, 1088, 128, need // 3)
    assert 64 <= rows < 576 and band_bytes(rows + 2 * CHUNK_OVERLAP_ROWS, 1088, 128) <= need // 3
    assert band_bytes(rows + 2 * CHUNK_OVERLAP_ROWS + 64, 1088, 128) > need // 3  # the most
    with pytest.raises(SGMMemoryError, match=r"memory_mb.*--matcher-memory") as err:
        chunk_rows(40_000, 40_000, 256, 2**30, "a test budget")
    assert "a test budget" in str(err.value) and isinstance(err.value, MemoryError)
    budget, source = memory_budget()
    assert budget > 0 and "memory" in source
    with pytest.raises(ValueError, match="memory_mb 0"):
        SGMSettings(memory_mb=0)
    left8 = np.zeros((64, 64), np.uint8)
    with pytest.raises(SGMMemoryError, match="needs"):
        sgm_disparity(left8, left8, 0, 15, SGMSettings(matcher="jax", memory_mb=0.01))
    # a budget past what the machine has is capped at it (the band would be killed mid-run):
    # a band larger than the host's memory is refused, naming the cap
    huge = np.zeros((64, 2**16), np.uint8)
    with pytest.raises(SGMMemoryError, match="as set, capped at the host's available memory"):
        census_sgm(huge, huge, 0, 2**15, PEN, memory_bytes=2**60)


def test_a_band_matched_in_chunks_equals_one_pass():
    """A budget for a quarter of the band: the chunks (one shape, one program) give the
    disparities of one pass over the band, up to the vertical paths' reach beyond the overlap."""
    left = _texture(300, 150, seed=4)
    left8, right8 = _uint8(left, _shifted(left, -5.4))
    whole = census_sgm(left8, right8, -12, 3, PEN)
    budget = band_bytes(128, 150, 16)  # chunks of 64 rows and their overlaps
    assert chunk_rows(300, 150, 16, budget) == 64
    before = _match._cache_size()
    chunked = census_sgm(left8, right8, -12, 3, PEN, memory_bytes=budget)
    assert _match._cache_size() - before <= 1  # all chunks share one program
    assert chunked.shape == whole.shape
    same = np.isclose(chunked, whole, atol=1e-6, equal_nan=True)
    assert same.mean() > 0.99, same.mean()
    assert np.nanmedian(np.abs(chunked[:, 20:-20] - (-5.4))) < 0.1


@pytest.fixture(scope="module")
def epipolar_tile():
    """The rectified pair of a rendered Cartosat-1 scene (seed 1; the matcher's penalties were
    chosen on seed 0) and the pipeline's disparity range."""
    from jaxgeo.models import fit_rpcs
    from jaxgeo.simulate._render import cartosat1_rendered

    rendered = cartosat1_rendered(1, size=320)
    scene = rendered.scene
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        paths = rendered.save_images(folder)
        truth = [rpc for rpc, _ in fit_rpcs([scene.truth[n] for n in scene.names],
                                            h_range=(100.0, 600.0))]  # fmt: skip
        settings = DSMSettings(triangulation="los_midpoint", band_rows=None)
        pair = stereo_pair(truth, [paths[n] for n in scene.names], settings, keep=True)
    return pair.intermediates["left"], pair.intermediates["right"], pair.stats


@pytest.mark.parametrize("paths", [8, 4])
def test_agrees_with_opencv_on_rendered_epipolar_tiles(epipolar_tile, paths):
    left, right, stats = epipolar_tile
    left8, right8 = to_uint8(left, stretch_limits(left)), to_uint8(right, stretch_limits(right))
    valid = np.isfinite(left)
    dmin, dmax = stats["disparity_range_px"]
    cv = sgm_disparity(left8, right8, dmin, dmax, SGMSettings(matcher="opencv"), valid=valid)
    jx = sgm_disparity(left8, right8, dmin, dmax, SGMSettings(matcher="jax", paths=paths),
                       valid=valid)  # fmt: skip
    assert jx.dtype == cv.dtype == np.float32
    fill_cv, fill_jax = np.isfinite(cv)[valid].mean(), np.isfinite(jx)[valid].mean()
    both = np.isfinite(cv) & np.isfinite(jx)
    assert np.mean(np.abs(cv - jx)[both] <= 1.0) >= 0.95
    # the issue's bar, for the default 8 paths (4 paths: 2.8 % less fill, measured)
    tol = 0.02 if paths == 8 else 0.04
    assert fill_cv > 0.8 and abs(fill_jax - fill_cv) <= tol, (fill_cv, fill_jax)


def _run(*argv) -> dict:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main([*argv, "--json", "--quiet"]) == 0
    return json.loads(out.getvalue())


def _height_errors(dsm_path, truth_path):
    """Median, NMAD and RMS (m) of the DSM minus the truth (nearest truth cell)."""
    import rasterio
    from rasterio.warp import Resampling, reproject

    with rasterio.open(dsm_path) as g, rasterio.open(truth_path) as s:
        truth = np.full((g.height, g.width), np.nan)
        reproject(rasterio.band(s, 1), truth, dst_transform=g.transform, dst_crs=g.crs,
                  resampling=Resampling.nearest, src_nodata=np.nan, dst_nodata=np.nan)  # fmt: skip
        height = g.read(1).astype(float)
    dh = (height - truth)[np.isfinite(height) & np.isfinite(truth)]
    med = float(np.median(dh))
    return {"n": dh.size, "median_m": med, "nmad_m": 1.4826 * np.median(np.abs(dh - med)),
            "rms_m": float(np.sqrt(np.mean(dh**2))),
            "over_1m": float(np.mean(np.abs(dh) > 1.0))}  # fmt: skip


def test_dsm_matcher_jax_as_accurate_as_opencv(tmp_path):
    """The issue's check on a small simulated scene (~10 s a run: the whole chain twice): the
    same NMAD, median and RMS. Measured (seed 23): RMS OpenCV 0.167 m, JAX 0.160 m; cells > 1 m
    off 0.11 % and 0.11 %. Before the census's tolerance (``CENSUS_TOLERANCE``) JAX's RMS was
    0.255 m with 1.4 % of the cells > 1 m off, in lines along the scene's uniform roads."""
    scene = tmp_path / "scene"
    _run("simulate", "stereo-scene", "--size", "300", "--seed", "23", "--exact-rpc",
         "--out", str(scene))  # fmt: skip
    err = {}
    for matcher in ("opencv", "jax"):
        out = tmp_path / f"dsm_{matcher}.tif"
        report = _run("dsm", str(scene / "left.tif"), str(scene / "right.tif"),
                      "--matcher", matcher, "-o", str(out))  # fmt: skip
        err[matcher] = _height_errors(out, scene / "truth_dsm.tif") | {"filled": report["filled"]}
    cv, jx = err["opencv"], err["jax"]
    assert cv["n"] > 20_000 and abs(jx["filled"] - cv["filled"]) < 0.02, err
    assert jx["nmad_m"] <= 1.1 * cv["nmad_m"] and jx["rms_m"] <= 1.15 * cv["rms_m"], err
    assert jx["over_1m"] < 0.004 and cv["over_1m"] < 0.004, err
    assert abs(jx["median_m"]) < 0.1, err


def test_agrees_with_opencv_on_a_real_pleiades_pair(shared_data):
    """The s2p triplet's img_02 / img_01 (Pleiades, a 350 px ROI), rectified by the pipeline;
    measured: fill 0.991 (OpenCV) and 0.988 (JAX), 98 % within 1 px."""
    from jaxgeo.io import read_rpc

    folder = shared_data / "s2p_triplet"
    paths = [folder / "img_02.tif", folder / "img_01.tif"]
    settings = DSMSettings(roi=(300, 300, 350, 350), band_rows=None)
    pair = stereo_pair([read_rpc(p) for p in paths], paths, settings, keep=True)
    left, right = pair.intermediates["left"], pair.intermediates["right"]
    left8, right8 = to_uint8(left, stretch_limits(left)), to_uint8(right, stretch_limits(right))
    valid = np.isfinite(left)
    drange = pair.stats["disparity_range_px"]
    cv = sgm_disparity(left8, right8, *drange, SGMSettings(matcher="opencv"), valid=valid)
    jx = sgm_disparity(left8, right8, *drange, SGMSettings(matcher="jax"), valid=valid)
    fill_cv, fill_jax = np.isfinite(cv)[valid].mean(), np.isfinite(jx)[valid].mean()
    both = np.isfinite(cv) & np.isfinite(jx)
    assert fill_cv > 0.9 and abs(fill_jax - fill_cv) <= 0.02, (fill_cv, fill_jax)
    assert np.mean(np.abs(cv - jx)[both] <= 1.0) >= 0.95
