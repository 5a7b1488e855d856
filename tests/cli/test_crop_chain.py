"""The chain a user runs on crops of a product (issue 51): match -> adjust -> ortho / dsm with
the adjusted models, on the real Ventoux Pleiades crops (500 px, the full product's ``.geom``,
the crop origin in a pixel-space geotransform).

Before: ``adjust`` wrote its RPCs in the crops' pixels and every reader applied the crop origin
again: the ortho exited 0 3.5 km away, the DSM stopped with "does not see the ROI", and
``--model IMG=adjusted_models.json`` was refused. Now the adjusted models are in the product's
frame (docs/conventions.md, "Pixel frames of crops"): the ortho with the adjusted RPC file or
``adjusted_models.json`` lands where the unadjusted one does, moved by the bias only, and the
DSM fills as with the delivered models.

The module runs the real chain once (match, adjust: ~70 s on the 2-core machine) and each
product three times (delivered, RPC file, JSON); a test needs the whole chain, hence its length.
"""

import json

import numpy as np
import pytest
import rasterio

from jaxgeo.cli import main
from jaxgeo.io import open_image


@pytest.fixture(scope="module")
def chain(real_data, tmp_path_factory):
    d = real_data / "ventoux"
    work = tmp_path_factory.mktemp("chain")
    images = [str(d / "left_image.tif"), str(d / "right_image.tif")]
    models = {
        "left_image": str(real_data / "phr_ventoux__left_image.geom"),
        "right_image": str(real_data / "phr_ventoux__right_image.geom"),
    }
    dem = ["--dem", str(d / "dem" / "N44E005_srtm90.tif"),
           "--geoid", str(d / "dem" / "egm96_15_crop_lon3-8_lat42-47.gtx")]  # fmt: skip
    given = [a for n, f in models.items() for a in ("--model", f"{n}={f}")]
    ties = work / "ties.csv"
    assert main(["match", *images, *given, *dem, "-o", str(ties), "--quiet"]) == 0
    out = work / "adjusted"
    assert main(["adjust", *images, *given, "--observations", str(ties), "--bias", "shift",
                 "-o", str(out), "--quiet"]) == 0  # fmt: skip
    return {"images": images, "models": models, "dem": dem, "out": out, "work": work}


def _model_sets(chain):
    out = chain["out"]
    return {
        "delivered": chain["models"],
        "rpc": {n: str(out / f"{n}_RPC.TXT") for n in chain["models"]},
        "json": {n: str(out / "adjusted_models.json") for n in chain["models"]},
    }


def _run(capsys, argv):
    assert main([*argv, "--json", "--quiet"]) == 0
    return json.loads(capsys.readouterr().out)


def test_ortho_with_the_adjusted_models_lands_where_the_delivered_one_does(chain, capsys):
    work, image = chain["work"], chain["images"][0]
    bounds = {}
    for kind, models in _model_sets(chain).items():
        path = work / f"ortho_{kind}.tif"
        argv = ["ortho", image, "--model", f"left_image={models['left_image']}", *chain["dem"],
                "-o", str(path)]  # fmt: skip
        report = _run(capsys, argv)
        assert report["valid_fraction"] > 0.85
        bounds[kind] = np.asarray(report["bounds"])
    # the RPC file and the JSON: one model, one product
    with rasterio.open(work / "ortho_rpc.tif") as a, rasterio.open(work / "ortho_json.tif") as b:
        assert a.transform == b.transform and np.array_equal(a.read(), b.read())
    # the delivered and adjusted products differ by the bias: the ground shift of the crop's
    # centre between the two models (at the terrain's height), to 1 px (0.5 m)
    from pyproj import Transformer

    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True)
    centre = []
    for models in (_model_sets(chain)["delivered"], _model_sets(chain)["json"]):
        m = open_image(image, model=models["left_image"]).model
        lon, lat, _ = np.asarray(m.localize(np.array([[249.5, 249.5]]), np.array([535.0])))[0]
        centre.append(np.asarray(to_utm.transform(lon, lat)))
    expected = centre[1] - centre[0]
    moved = (bounds["json"] - bounds["delivered"]).reshape(2, 2).mean(axis=0)
    # measured (2-core VM): the bias (-2.32, -0.62) px moves the ortho by (-0.99, 0.34) m,
    # expected (-1.05, 0.29) m; before, the adjusted RPC's ortho was 3536 m away
    assert 0.3 < np.linalg.norm(expected) < 3.0
    assert np.linalg.norm(moved - expected) < 0.5


def test_dsm_with_the_adjusted_models_fills_as_with_the_delivered_ones(chain, capsys):
    fills, across = {}, {}
    for kind, models in _model_sets(chain).items():
        if kind == "rpc":
            continue  # the same models as the JSON (the ortho test shows it); 20 s saved
        given = [a for n, f in models.items() for a in ("--model", f"{n}={f}")]
        argv = ["dsm", *chain["images"], *given, *chain["dem"], "--res", "1",
                "-o", str(chain["work"] / f"dsm_{kind}.tif")]  # fmt: skip
        report = _run(capsys, argv)
        fills[kind] = report["filled"]
        across[kind] = report["pairs"][0]["ties_across_px"]
    # measured (2-core VM, 0.5 m cells): 0.208 delivered, 0.2075 adjusted; before, the DSM
    # with the adjusted RPCs stopped ("does not see the ROI")
    assert fills["delivered"] > 0.15
    assert abs(fills["json"] - fills["delivered"]) < 0.03
    # the adjustment took out the pair's offset across the epipolar curves (-4.75 px)
    assert abs(across["delivered"]) > 3.0 and abs(across["json"]) < 0.5
