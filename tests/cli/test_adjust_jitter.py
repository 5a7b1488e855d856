"""``jaxgeo adjust --bias jitter`` end to end: ties of a jittered pair in, an RPC per image
and its jitter grid out, and the written files remove the waves across the epipolar direction.

The pair is :func:`jaxgeo.simulate.stereo_scene_truth` (800 px, a 1.5 px jitter of period 400
lines, exact RPCs fitted without it; seed 5170, used nowhere else), not rendered: the ties are
terrain points projected through the true jittered models, plus 0.1 px of noise. The check
reads only what the command wrote: each image's RPC and ``<image>_jitter.csv`` (``image =
RPC(ground) + (dx, dy)`` at the RPC's line), and measures the noise-free ties' offsets across
the epipolar direction with the RPCs alone and with the grids applied.
"""

import json

import numpy as np
import pytest

from jaxgeo.cli import main
from jaxgeo.io import read_rpc
from jaxgeo.io.internal import format_rpc_txt
from jaxgeo.simulate import StereoSceneSettings, stereo_scene_truth
from jaxgeo.simulate._stereo_scene_models import localize_on_terrain_exact, project_true
from jaxgeo.stereo import epipolar_offsets

SIZE, PERIOD, SEED, NOISE_PX = 800, 400.0, 5170, 0.1


def _ties(scene):
    g = np.linspace(10, SIZE - 11, 40)
    xy1 = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    ground = localize_on_terrain_exact(scene.truth["left"], scene.terrain, xy1)
    ok = np.all(np.isfinite(ground), axis=1)
    xy1, ground = xy1[ok], ground[ok]
    xy2 = np.asarray(project_true(scene.truth["right"], ground))
    inside = np.all((xy2 > 0) & (xy2 < SIZE - 1), axis=1)
    h = ground[inside, 2]
    return xy1[inside], xy2[inside], (h.min() - 50, h.max() + 50)


def _across_rms(rpcs, xy1, xy2, h_range) -> float:
    d = np.asarray(epipolar_offsets(rpcs["left"], rpcs["right"], xy1, xy2, h_range))
    return float(np.sqrt(np.mean(d**2)))


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("jitter")
    scene = stereo_scene_truth(SIZE, SEED, StereoSceneSettings(
        jitter_px=1.5, jitter_period_lines=PERIOD, exact_rpc=True))  # fmt: skip
    xy1, xy2, h_range = _ties(scene)
    rng = np.random.default_rng(SEED)
    lines = ["id,image,x,y,sigma_px"]
    for name, xy in (("left", xy1), ("right", xy2)):
        (folder / f"{name}_RPC.TXT").write_text(format_rpc_txt(scene.rpcs[name]))
        noisy = xy + rng.normal(0, NOISE_PX, xy.shape)
        lines += [f"T{i:05d},{name},{x:.4f},{y:.4f},0.2" for i, (x, y) in enumerate(noisy)]
    (folder / "obs.csv").write_text("\n".join(lines) + "\n")
    out = folder / "out"
    code = main([
        "adjust", "--image", f"left={folder / 'left_RPC.TXT'}",
        "--image", f"right={folder / 'right_RPC.TXT'}", "--observations", str(folder / "obs.csv"),
        "--bias", "jitter", "--jitter-knot-lines", str(PERIOD / 8), "--jitter-smoothness-px",
        "0.3", "--loss", "l2", "--keep-blunders", "-o", str(out), "--quiet",
    ])  # fmt: skip
    return code, out, xy1, xy2, h_range


def test_jitter_grids_written_beside_the_rpcs(adjusted):
    code, out, *_ = adjusted
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    for name in ("left", "right"):
        grid = np.loadtxt(out / f"{name}_jitter.csv", delimiter=",", skiprows=1)
        assert grid.shape[1] == 3 and np.all(np.diff(grid[:, 0]) > 0)
        assert grid[0, 0] <= 0 and grid[-1, 0] >= SIZE - 1  # over every line
        assert report["rpc_files"][name]["files"]
    assert "jitter correction along the lines" in (out / "report.txt").read_text()


def test_written_rpcs_and_grids_remove_the_waves(adjusted):
    code, out, xy1, xy2, h_range = adjusted
    report = json.loads((out / "report.json").read_text())
    rpcs = {n: read_rpc(report["rpc_files"][n]["files"][0]) for n in ("left", "right")}
    grids = {n: np.loadtxt(out / f"{n}_jitter.csv", delimiter=",", skiprows=1) for n in rpcs}

    def to_rpc(name, xy):  # image = RPC(ground) + c(line): the RPC's pixel is image - c
        g = grids[name]
        c = np.stack([np.interp(xy[:, 1], g[:, 0], g[:, k]) for k in (1, 2)], axis=1)
        return xy - c

    without = _across_rms(rpcs, xy1, xy2, h_range)
    corrected = _across_rms(rpcs, to_rpc("left", xy1), to_rpc("right", xy2), h_range)
    # measured (2-core CPU): without the grids 0.61 px (the jitter the RPCs cannot hold), with
    # them 0.037 px (noise-free ties; the grids reach 1.43 and 1.30 px across track)
    assert without > 0.5
    assert corrected < 0.2
    assert without / corrected > 3.0


def test_a_dem_with_the_jitter_bias_is_noted(adjusted, tmp_path, capsys):
    """The DEM's heights fix the along-track jitter the ties leave open, its own errors
    included (benchmarks/accuracy/jitter_dsm.py): the command says so, even with --quiet."""
    import rasterio
    from rasterio.transform import from_bounds

    _, out, *_ = adjusted
    folder = out.parent
    rpc = read_rpc(folder / "left_RPC.TXT")
    lon, lat, h = (float(v) for v in rpc.ground_offset)
    dem = tmp_path / "flat.tif"
    profile = dict(driver="GTiff", width=8, height=8, count=1, dtype="float32",
                   crs="EPSG:4326", transform=from_bounds(lon - 0.05, lat - 0.05, lon + 0.05,
                                                          lat + 0.05, 8, 8))  # fmt: skip
    with rasterio.open(dem, "w", **profile) as dst:
        dst.write(np.full((1, 8, 8), h, np.float32))
    code = main([
        "adjust", "--image", f"left={folder / 'left_RPC.TXT'}",
        "--image", f"right={folder / 'right_RPC.TXT'}", "--observations", str(folder / "obs.csv"),
        "--bias", "jitter", "--jitter-knot-lines", str(PERIOD / 8), "--dem", str(dem),
        "--tie-height-sigma-m", "100", "--loss", "l2", "--keep-blunders", "--quiet",
    ])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0, err
    assert "with --bias jitter the heights of" in err and "own errors" in err
