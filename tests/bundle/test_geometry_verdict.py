"""A block without GCPs checks its geometry (issue 53): tie points fit swapped or foreign models
with a small s0 (the affine biases absorb the rest), but the ties then lie far outside the
models' validity heights (or the DEM's), their rays do not meet, or the biases move far beyond
their priors; each is a :class:`PoorFitWarning` naming the images (``jaxgeo adjust`` exit 3).
On s2p's 481 real matches between the Pleiades views img_01 and img_02 (valid heights
40..1090 m, terrain ~80..330 m)."""

import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from jaxgeo.bundle import AdjustSettings, PoorFitWarning, adjust
from jaxgeo.bundle._adjustment import bias_prior_sigma, with_bias
from jaxgeo.bundle._diagnose import RAY_MISS_PX, geometry_verdict, ray_reasons
from jaxgeo.bundle._prepare import prepare
from jaxgeo.io import Observations, open_image


@pytest.fixture(scope="module")
def s2p(shared_data):
    d = shared_data / "s2p_triplet"
    images = {n: open_image(d / f"{n}.tif") for n in ("img_01", "img_02", "img_03")}
    m = np.loadtxt(d / "matches_on_rpc_roi_img01_img02.txt")
    ids = tuple(f"T{i:03d}" for i in range(len(m)))
    obs = Observations(
        ids * 2, ("img_01",) * len(m) + ("img_02",) * len(m),
        np.concatenate([m[:, :2], m[:, 2:]]), np.full(2 * len(m), 0.5),
    )  # fmt: skip
    return images, obs


def _settings(images, **more):
    # the priors jaxgeo adjust gives a block without GCPs (bundle._files.RELATIVE_PRIOR_*)
    domains = {n: im.domain() for n, im in images.items()}
    return AdjustSettings(
        bias_prior_shift_px=10.0, bias_prior_matrix=1e-4, image_domains=domains, **more
    )


def _adjust(images, obs, models, **more):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = adjust(models, obs, bias="affine", settings=_settings(images, **more))
    poor = [str(w.message) for w in caught if issubclass(w.category, PoorFitWarning)]
    return r, poor


def test_valid_pair_passes(s2p):
    images, obs = s2p
    models = {n: images[n].model for n in ("img_01", "img_02")}
    r, poor = _adjust(images, obs, models)
    assert poor == [] and r.poor_fit == ""
    h = r.ground[:, 2]
    assert 60 < np.percentile(h, 5) and np.percentile(h, 95) < 400  # the terrain, in range


def test_swapped_rpcs_are_declared(s2p):
    images, obs = s2p
    models = {"img_01": images["img_02"].model, "img_02": images["img_01"].model}
    r, poor = _adjust(images, obs, models)
    assert r.s0 < 1.0  # the fit alone does not show it
    assert len(poor) == 1 and r.poor_fit == poor[0]
    text = poor[0]
    assert "leave the models' validity range (40..1090 m)" in text
    assert "of the ties of image 'img_01'" in text and "of the ties of image 'img_02'" in text
    assert "far from the given one" in text and "img_01.bias.matrix[0,0]" in text
    assert "two RPC files swapped" in text


def test_model_of_another_view_is_declared(s2p):
    images, obs = s2p
    models = {"img_01": images["img_03"].model, "img_02": images["img_02"].model}
    r, poor = _adjust(images, obs, models)
    assert len(poor) == 1 and "leave the models' validity range" in poor[0]
    assert np.percentile(r.ground[:, 2], 95) < 0  # below the ellipsoid: not the terrain


def test_ties_far_from_the_dem_heights(s2p):
    """A DEM 800 m above the terrain (another place, a wrong unit or datum) given as tie
    heights: the ties leave the DEM's heights, or the biases their priors (both named)."""
    images, obs = s2p
    models = {n: images[n].model for n in ("img_01", "img_02")}

    def dem(lonlat):
        return np.full(len(lonlat), 1000.0)

    r, poor = _adjust(images, obs, models, tie_height=dem)
    assert len(poor) == 1
    assert "the DEM of the tie heights (--dem): its heights differ" in poor[0]
    assert "a constant offset of +887 m" in poor[0]  # the ties' own heights: 90..142 m
    assert "far from the given one" in poor[0]  # pulled up to it, the biases left their priors
    assert "or a DEM of tie heights that is not the terrain's" in poor[0]


def test_rays_that_do_not_meet(s2p):
    """img_02's model moved 400 px across the epipolar lines: the rays miss by ~200 px each
    before any adjustment; named with the images (checked on the prepared block: the solve with
    10 px priors would then also move the biases far beyond them)."""
    images, obs = s2p
    good = {n: images[n].model for n in ("img_01", "img_02")}
    rpc = good["img_02"]  # an RPC: moved by its image offset, one group with img_01's
    off = dict(good, img_02=eqx.tree_at(lambda m: m.image_offset, rpc,
                                        rpc.image_offset + jnp.array([400.0, 0.0])))  # fmt: skip
    for models, expect in ((good, False), (off, True)):
        b = with_bias(models, "affine")
        setup = prepare(b, obs, prior_sigma=bias_prior_sigma(b, 10.0, 1e-4),
                        settings=_settings(images), check_control=False)  # fmt: skip
        reasons = ray_reasons(setup)
        assert bool(reasons) == expect, reasons
    assert "the rays of images 'img_01', 'img_02' do not meet" in reasons[0]
    assert f"above {RAY_MISS_PX:g} px" in reasons[0]


def test_with_gcps_the_fit_decides(s2p):
    """The geometry verdict is for blocks without GCPs; with GCPs, snooping and s0 decide."""
    images, obs = s2p
    models = with_bias({n: images[n].model for n in ("img_01", "img_02")}, "affine")
    from jaxgeo.io import GroundPoints

    ground = GroundPoints(("T000",), np.array([[5.44, 43.26, 200.0]]), ("gcp",),
                          np.full((1, 3), 1.0))  # fmt: skip
    setup = prepare(models, obs, ground, settings=_settings(images), check_control=False)
    assert geometry_verdict(setup, None) == []


def test_cli_swapped_rpcs_without_gcps_exit_3(shared_data, tmp_path, capsys):
    """The README's chain without GCPs: ``jaxgeo adjust`` with the RPCs of img_01 and img_02
    swapped (``--model``) ends with exit 3 and the warning naming both images; as given, 0."""
    from jaxgeo.cli import main
    from jaxgeo.io import write_observations

    d = shared_data / "s2p_triplet"
    images, obs = _s2p_for_cli(shared_data)
    write_observations(obs, tmp_path / "ties.csv")
    base = [str(d / "img_01.tif"), str(d / "img_02.tif"), "--observations",
            str(tmp_path / "ties.csv"), "--quiet"]  # fmt: skip
    swap = ["--model", f"img_01={d / 'img_02.tif'}", "--model", f"img_02={d / 'img_01.tif'}"]
    assert main(["adjust", *base, "-o", str(tmp_path / "ok")]) == 0
    capsys.readouterr()
    assert main(["adjust", *base, *swap, "-o", str(tmp_path / "swapped")]) == 3
    err = capsys.readouterr().err
    assert "Traceback" not in err and "do not fit the geometry of the models" in err
    assert "'img_01'" in err and "'img_02'" in err


def _s2p_for_cli(shared_data):
    d = shared_data / "s2p_triplet"
    images = {n: open_image(d / f"{n}.tif") for n in ("img_01", "img_02")}
    m = np.loadtxt(d / "matches_on_rpc_roi_img01_img02.txt")
    ids = tuple(f"T{i:03d}" for i in range(len(m)))
    obs = Observations(
        ids * 2, ("img_01",) * len(m) + ("img_02",) * len(m),
        np.concatenate([m[:, :2], m[:, 2:]]), np.full(2 * len(m), 0.5),
    )  # fmt: skip
    return images, obs
