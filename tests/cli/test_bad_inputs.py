"""The table of bad inputs (issue "A real user's chain, trusted"): each case through the CLI is a
named error (exit status != 0, one line, no traceback) or a warning naming the problem, and no
input file changes. Cases that need the s2p triplet skip without it."""

import hashlib
import pathlib
import shutil
import warnings

import numpy as np
import pytest
import rasterio

from jaxgeo.cli import main

REAL = pathlib.Path(__file__).parents[1] / "data" / "real"
VENTOUX = REAL / "ventoux"


def digest(path) -> str:
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


@pytest.fixture
def workspace(tmp_path, shared_data):
    """Copies of the inputs (the s2p triplet, the Ventoux crops and models, SRTM, the demo
    scene) in a folder of their own, so that no case can touch the originals."""
    src = tmp_path / "in"
    src.mkdir()
    for name in ("img_01.tif", "img_02.tif", "img_03.tif"):
        shutil.copy(shared_data / "s2p_triplet" / name, src / name)
    for name in ("left_image.tif", "right_image.tif"):
        shutil.copy(VENTOUX / name, src / name)
    for side in ("left", "right"):
        shutil.copy(REAL / f"phr_ventoux__{side}_image.geom", src / f"{side}.geom")
    shutil.copy(VENTOUX / "dem" / "N44E005_srtm90.tif", src / "srtm.tif")
    shutil.copy(VENTOUX / "dem" / "egm96_15_crop_lon3-8_lat42-47.gtx", src / "egm96.gtx")
    out = tmp_path / "out"
    out.mkdir()
    hashes = {p: digest(p) for p in src.iterdir()}
    yield src, out
    for path, value in hashes.items():
        assert digest(path) == value, f"{path.name} changed"
    assert sorted(p.name for p in src.iterdir()) == sorted(p.name for p in hashes)


def voids_dem(src: pathlib.Path, folder: pathlib.Path) -> pathlib.Path:
    """The SRTM tile with its -32768 voids no longer declared nodata, and a void on the crop."""
    with rasterio.open(src / "srtm.tif") as f:
        z, profile = f.read(1), f.profile
    profile.update(nodata=None)
    z = z.copy()
    z[948:950, 236:238] = -32768  # a corner of the Ventoux crop (lon 5.197, lat 44.209)
    out = folder / "voids.tif"
    with rasterio.open(out, "w", **profile) as f:
        f.write(z, 1)
    return out


VENT = ["--model", "left_image=left.geom", "--model", "right_image=right.geom"]

# (case, argv with {in}/{out} placeholders, expected exit status, words of the message)
CASES = [
    ("dsm: output named as an input, with --overwrite",
     ["dsm", "{in}/img_02.tif", "{in}/img_01.tif", "--overwrite", "-o", "{in}/img_01.tif"], 2,
     "is an input of the command"),
    ("dsm: geographic CRS with a resolution in metres",
     ["dsm", "{in}/img_02.tif", "{in}/img_01.tif", "--crs", "EPSG:4326", "--res", "0.5",
      "-o", "{out}/d.tif"], 2, "not a projected CRS"),
    ("dsm: invalid CRS", ["dsm", "{in}/img_02.tif", "{in}/img_01.tif", "--crs", "EPSG:0",
                          "-o", "{out}/d.tif"], 2, "not a CRS PROJ knows"),
    ("dsm: --res 0.0005 (a product too large)",
     ["dsm", "{in}/img_02.tif", "{in}/img_01.tif", "--res", "0.0005", "-o", "{out}/d.tif"], 2,
     "more than --max-cells"),
    ("dsm: --res 1e6 (1 x 1 cell)",
     ["dsm", "{in}/img_02.tif", "{in}/img_01.tif", "--res", "1e6", "-o", "{out}/d.tif"], 2,
     "lower --res"),
    ("dsm: output under a file",
     ["dsm", "{in}/img_02.tif", "{in}/img_01.tif", "-o", "{in}/img_01.tif/d.tif"], 2,
     "is not a folder"),
    ("dsm: ROI outside the image",
     ["dsm", "{in}/img_02.tif", "{in}/img_01.tif", "--roi", "900", "0", "500", "500",
      "-o", "{out}/d.tif"], 2, "not inside"),
    ("dsm: crop origin given against the crop's own frame",
     ["dsm", "{in}/left_image.tif", "{in}/right_image.tif", *VENT,
      "--image-origin", "left_image=0,0", "-o", "{out}/d.tif"], 2, "conflicts with the crop"),
    ("dsm: a crop without its model", ["dsm", "{in}/left_image.tif", "{in}/right_image.tif",
                                       "-o", "{out}/d.tif"], 2, "no sensor model in the image"),
    ("match: heights reversed",
     ["match", "{in}/img_01.tif", "{in}/img_02.tif", "--heights", "500", "-500",
      "-o", "{out}/t.csv"], 2, "--heights"),
    ("match: sigma 0", ["match", "{in}/img_01.tif", "{in}/img_02.tif", "--sigma", "0",
                        "-o", "{out}/t.csv"], 2, "--sigma"),
    ("match: ROI outside the image",
     ["match", "{in}/img_01.tif", "{in}/img_02.tif", "--roi", "2000", "0", "100", "100",
      "-o", "{out}/t.csv"], 2, "--roi"),
    ("match: output named as an input, with --overwrite",
     ["match", "{in}/img_01.tif", "{in}/img_02.tif", "--overwrite", "-o", "{in}/img_02.tif"], 2,
     "is an input of the command"),
    ("ortho: output named as the DEM, with --overwrite",
     ["ortho", "{in}/left_image.tif", "--model", "left.geom", "--dem", "{in}/srtm.tif",
      "--geoid", "{in}/egm96.gtx", "--overwrite", "-o", "{in}/srtm.tif"], 2,
     "is an input of the command"),
    ("ortho: geographic CRS with a resolution in metres",
     ["ortho", "{in}/left_image.tif", "--model", "left.geom", "--dem", "{in}/srtm.tif",
      "--geoid", "{in}/egm96.gtx", "--crs", "EPSG:4326", "--res", "0.5", "-o", "{out}/o.tif"],
     2, "degrees"),
    ("ortho: invalid CRS",
     ["ortho", "{in}/left_image.tif", "--model", "left.geom", "--dem", "{in}/srtm.tif",
      "--geoid", "{in}/egm96.gtx", "--crs", "EPSG:0", "-o", "{out}/o.tif"], 2, "CRS"),
    ("ortho: bounds outside the footprint",
     ["ortho", "{in}/left_image.tif", "--model", "left.geom", "--dem", "{in}/srtm.tif",
      "--geoid", "{in}/egm96.gtx", "--crs", "EPSG:32631", "--bounds", "0", "0", "100", "100",
      "-o", "{out}/o.tif"], 2, "footprint"),
    ("ortho: --res 1e6 (1 x 1 px)",
     ["ortho", "{in}/left_image.tif", "--model", "left.geom", "--dem", "{in}/srtm.tif",
      "--geoid", "{in}/egm96.gtx", "--res", "1e6", "-o", "{out}/o.tif"], 2, "--res"),
    ("ortho: --res 0.0005 (a product too large)",
     ["ortho", "{in}/left_image.tif", "--model", "left.geom", "--dem", "{in}/srtm.tif",
      "--geoid", "{in}/egm96.gtx", "--res", "0.0005", "-o", "{out}/o.tif"], 2, "pixels"),
]  # fmt: skip


CASES = [pytest.param(*case) for case in CASES]


@pytest.mark.parametrize("case, argv, status, words", CASES, ids=[c.values[0] for c in CASES])
def test_bad_input_is_a_named_error(workspace, capsys, monkeypatch, case, argv, status, words):
    src, out = workspace
    monkeypatch.chdir(src)  # model files named relative to the inputs
    args = [a.replace("{in}", str(src)).replace("{out}", str(out)) for a in argv]
    assert main([*args, "--quiet"]) == status, capsys.readouterr().err
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.startswith(f"jaxgeo {argv[0]}: error: "), err
    assert len(err.strip().splitlines()) == 1, err
    assert words in err, err
    assert list(out.iterdir()) == []  # nothing written


def test_undeclared_dem_voids_are_nodata_with_a_warning(workspace, tmp_path, capsys,
                                                        monkeypatch):  # fmt: skip
    src, out = workspace
    dems = tmp_path / "dems"
    dems.mkdir()
    dem = voids_dem(src, dems)
    monkeypatch.chdir(src)
    argv = ["ortho", str(src / "left_image.tif"), "--model", "left.geom", "--dem", str(dem),
            "--geoid", str(src / "egm96.gtx"), "-o", str(out / "o.tif")]  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        status = main(argv)
    err = capsys.readouterr().err
    said = err + " ".join(str(w.message) for w in caught)
    assert "-32768" in said and "nodata" in said, said  # the warning names the problem
    assert "Traceback" not in err
    if status == 0:  # the void is nodata in the ortho, never heights of -32768 m
        with rasterio.open(out / "o.tif") as f:
            data = f.read(1, masked=True)
        assert 0 < np.ma.count_masked(data) < data.size
    else:
        assert status == 2 and "nodata" in err
