"""``jaxgeo adjust`` on a pair controlled through tie points (issue 11): 2 000 simulated ties with
1 % gross errors, GCPs measured in one image only, affine bias with priors (the scale case of
``benchmarks/speed/adjust_scale.py``, small)."""

import csv
import json

import numpy as np
import pytest

from jaxgeo.cli import main
from jaxgeo.simulate._tiepair import tie_pair


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    p = tie_pair(2000, seed=1)
    return p, p.save(tmp_path_factory.mktemp("ties"))


def _args(files, *extra):
    return [
        "adjust", "--image", f"fore={files['fore']}", "--image", f"aft={files['aft']}",
        "--ground", str(files["ground"]), "--observations", str(files["observations"]),
        "--bias", "affine", *extra,
    ]  # fmt: skip


def test_ties_only_image_adjusted_with_priors(pair, tmp_path, capsys):
    p, files = pair
    out = tmp_path / "out"
    priors = ("--bias-prior-shift-px", "5", "--bias-prior-matrix", "1e-3")
    assert main(_args(files, *priors, "--loss", "l2", "--json", "--out", str(out))) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["converged"] and 0.4 < data["s0"] < 0.8  # 0.3 px noise, sigma 0.5 px
    with open(out / "residuals.csv") as f:
        rows = list(csv.DictReader(f))
    flagged = np.array([r["blunder"] == "1" for r in rows])
    tie = np.array([r["id"].startswith("T") for r in rows])
    v = np.array([[float(r["vx_px"]), float(r["vy_px"])] for r in rows])
    img = np.array([r["image"] for r in rows])
    for name in ("fore", "aft"):
        mean = np.mean(v[tie & ~flagged & (img == name)], axis=0)
        assert np.all(np.abs(mean) < 0.01), (name, mean)
    # the gross errors are found: all that a two-ray point can show (the component across the
    # epipolar direction; along it a gross error only moves the point's height) ...
    detectable = p.detectable(4.0)
    assert detectable.sum() > 30
    assert np.mean(flagged[detectable]) > 0.9  # 34 of 36 in this draw
    # ... and nothing else: a flagged clean observation is the other ray of a bad point
    bad_points = {rows[i]["id"] for i in np.flatnonzero(p.gross)}
    assert all(rows[i]["id"] in bad_points for i in np.flatnonzero(flagged & ~p.gross))
    # the report names the first 50 of them and says where the others are
    line = next(ln for ln in (out / "report.txt").read_text().splitlines() if "gross err" in ln)
    n = int(flagged.sum())
    assert n > 50 and f"({n} observations)" in line
    assert line.count("@") == 50 and f"({n - 50} more: the 'blunder' column of residuals" in line
    # the aft bias across the epipolar direction (x) is found through the ties alone
    aft = data["images"]["aft"]["params"]
    assert abs(aft[".bias.shift_px[0]"] - 1.2) < 0.3


def test_tie_heights_from_a_dem_raster(pair, tmp_path, capsys):
    """``--dem FILE``: a GeoTIFF of the simulated terrain (EPSG:4326, ellipsoidal heights) gives
    every tie a height observation; with it the along-track parallax (aft shift against the tie
    heights) is fixed without a shift prior, and the aft shift comes out as simulated (1.34,
    -0.89 px for 1.2, -0.8 in this draw)."""
    import rasterio

    from jaxgeo.io import read_rpc
    from jaxgeo.simulate._tiepair import terrain_height

    p, files = pair
    rpc = read_rpc(files["fore"])
    off, sc = np.asarray(rpc.ground_offset, float), np.asarray(rpc.ground_scale, float)
    n, step = 400, 2.2 * sc[:2] / 400
    west, north = off[0] - 1.1 * sc[0], off[1] + 1.1 * sc[1]
    lon = west + (np.arange(n) + 0.5) * step[0]
    lat = north - (np.arange(n) + 0.5) * step[1]
    dem = terrain_height(*np.meshgrid(lon, lat), off)
    path = tmp_path / "dem.tif"
    with rasterio.open(
        path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float64", crs="EPSG:4326",
        transform=rasterio.Affine(step[0], 0.0, west, 0.0, -step[1], north),
    ) as f:  # fmt: skip
        f.write(dem, 1)
    args = _args(files, "--bias-prior-matrix", "1e-3", "--dem", str(path), "--loss", "l2")
    assert main([*args, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["converged"] and 0.4 < data["s0"] < 0.8
    aft = data["images"]["aft"]["params"]
    truth = json.loads(files["truth"].read_text())["bias"]["aft"]["shift_px"]  # [1.2, -0.8]
    assert abs(aft[".bias.shift_px[0]"] - truth[0]) < 0.3
    assert abs(aft[".bias.shift_px[1]"] - truth[1]) < 0.3
    # without the DEM (and without a shift prior) the row shift is undetermined, and named
    assert main([*_args(files, "--bias-prior-matrix", "1e-3", "--loss", "l2")]) == 2
    err = capsys.readouterr().err
    assert "not determined" in err and "aft.bias.shift_px[1]" in err and "--dem" in err
