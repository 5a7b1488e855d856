"""A jitter spline is never left undetermined (issue 51, item 3): default priors hold what the
ties do not observe, the knots are placed from the image's lines and measurements, and a
spacing the measurements cannot support is refused naming ``--jitter-knot-lines``.

The block: :func:`jaxgeo.simulate.stereo_scene_truth` (400 px, a 1.5 px jitter of period 400
lines, exact RPCs fitted without it; seed 5121, used nowhere else), not rendered: ties are
terrain points projected through the true jittered models plus 0.1 px of noise, ~560 on the
first 260 lines of the left image only, so that the last knots have no measurement. Ties
only, no DEM: the offsets common to both images and those along the epipolar direction are
not observed. With a knot every 50 lines, a loose smoothness prior (10 px: the knots held
loosely, as 33 knots under 117 000 ties on a 3000 px scene were) and the priors
``--bias-prior-shift-px 10 --bias-prior-matrix 1e-3``, this block stopped before issue 51 with
"singular normal equations" (measured on commit 5fbddd6: ``knots_px[0,1]``, ``[1,1]``, ... of
both images, the along-track knots, variance inflation 7.8e6).
"""

import json

import numpy as np
import pytest

from jaxgeo.bundle import AdjustmentError
from jaxgeo.bundle._prepare.jitter import (
    FLOOR_KNOT_LINES,
    MAX_AUTO_KNOTS,
    MAX_KNOTS,
    auto_knot_lines,
    check_knots,
)
from jaxgeo.cli import main
from jaxgeo.io.internal import format_rpc_txt
from jaxgeo.models import JitterBias
from jaxgeo.simulate import StereoSceneSettings, stereo_scene_truth
from jaxgeo.simulate._stereo_scene_models import localize_on_terrain_exact, project_true

SIZE, PERIOD, SEED, NOISE_PX, LAST_TIE_LINE = 400, 400.0, 5121, 0.1, 260.0


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    """RPC files and OBS.csv of the partly tied pair."""
    folder = tmp_path_factory.mktemp("jitter_priors")
    scene = stereo_scene_truth(SIZE, SEED, StereoSceneSettings(
        jitter_px=1.5, jitter_period_lines=PERIOD, exact_rpc=True))  # fmt: skip
    cols, rows = np.linspace(8, SIZE - 9, 20), np.linspace(8, LAST_TIE_LINE, 28)
    xy1 = np.stack(np.meshgrid(cols, rows), -1).reshape(-1, 2)
    ground = localize_on_terrain_exact(scene.truth["left"], scene.terrain, xy1)
    ok = np.all(np.isfinite(ground), axis=1)
    xy1, ground = xy1[ok], ground[ok]
    xy2 = np.asarray(project_true(scene.truth["right"], ground))
    inside = np.all((xy2 > 0) & (xy2 < SIZE - 1), axis=1)
    rng = np.random.default_rng(SEED)
    lines = ["id,image,x,y,sigma_px"]
    for name, xy in (("left", xy1[inside]), ("right", xy2[inside])):
        (folder / f"{name}_RPC.TXT").write_text(format_rpc_txt(scene.rpcs[name]))
        noisy = xy + rng.normal(0, NOISE_PX, xy.shape)
        lines += [f"T{i:04d},{name},{x:.4f},{y:.4f},0.2" for i, (x, y) in enumerate(noisy)]
    (folder / "obs.csv").write_text("\n".join(lines) + "\n")
    return folder


def _adjust(folder, *extra):
    return main([
        "adjust", "--image", f"left={folder / 'left_RPC.TXT'}",
        "--image", f"right={folder / 'right_RPC.TXT'}", "--observations", str(folder / "obs.csv"),
        "--bias-prior-shift-px", "10", "--bias-prior-matrix", "1e-3", "--loss", "l2",
        "--keep-blunders", "--quiet", *extra,
    ])  # fmt: skip


def test_ties_only_block_converges_with_its_priors_stated(block, capsys):
    out = block / "out"
    code = _adjust(block, "--bias", "jitter", "--jitter-knot-lines", "50",
                   "--jitter-smoothness-px", "10", "-o", str(out))  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0, err
    report = json.loads((out / "report.json").read_text())
    assert report["converged"] and "singular" not in report["message"]
    notes = "\n".join(report["notes"])
    assert "image 'left': jitter spline of 11 knots, one every 50 lines over lines 0..400" in notes
    assert "each spline coefficient 0 +- 5 px (--jitter-knot-sigma-px)" in notes
    assert "second differences +- 10 px" in notes and "mean and trend" in notes
    assert "each spline coefficient 0 +- 5 px" in (out / "report.txt").read_text()
    # every knot held (a finite sigma), none undetermined. Along the epipolar direction
    # (y) the ties observe nothing: the priors alone hold those knots, so their sigmas are the
    # same in both images and symmetric end to end; across it (x), the knots beyond the last
    # tie line are held more loosely than those the ties reach.
    sig = {
        name: np.array([[report["images"][name]["sigmas"][f".bias.knots_px[{i},{c}]"]
                         for c in (0, 1)] for i in range(11)])
        for name in ("left", "right")
    }  # fmt: skip
    for s in sig.values():
        assert np.all(np.isfinite(s) & (s > 0))
        np.testing.assert_allclose(s[:, 1], s[::-1, 1], rtol=1e-3)
        assert s[10, 0] > s[2:7, 0].max()
    np.testing.assert_allclose(sig["left"][:, 1], sig["right"][:, 1], rtol=1e-3)


def test_automatic_knots_are_stated(block):
    from jaxgeo.bundle import AdjustSettings, with_bias
    from jaxgeo.bundle._prepare import prepare
    from jaxgeo.io import read_observations, read_rpc

    models = with_bias({n: read_rpc(block / f"{n}_RPC.TXT") for n in ("left", "right")},
                       "jitter")  # fmt: skip
    assert models["left"].bias.auto_knots and models["left"].bias.knots_px.shape == (4, 2)
    settings = AdjustSettings(bias_prior_shift_px=10.0, bias_prior_matrix=1e-3)
    setup = prepare(models, read_observations(block / "obs.csv"), settings=settings,
                    prior_sigma=None, check_control=False)  # fmt: skip
    # ~560 ties over 252 lines: 20 per segment allows 9 lines; the floor, 100 lines, rules,
    # widened to a whole number of segments over the RPC's 399 lines
    assert "jitter spline of 6 knots, one every 133 lines over lines 0..399" in setup.notes[0]
    assert "chosen from its 399 lines and" in setup.notes[0], setup.notes


def test_knot_lines_given_beyond_what_the_ties_support_is_refused(block, capsys):
    assert _adjust(block, "--bias", "jitter", "--jitter-knot-lines", "1") == 2
    err = capsys.readouterr().err
    assert "--jitter-knot-lines" in err and "measurements support" in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("bias", ["affine", "shift"])
def test_jitter_options_refused_with_another_bias(block, capsys, bias):
    assert _adjust(block, "--bias", bias, "--jitter-knot-lines", "100") == 2
    err = capsys.readouterr().err
    assert "--jitter-knot-lines: only with --bias jitter" in err, err


def test_automatic_spacing_scales_with_the_lines_within_bounds():
    dense = lambda lines: np.linspace(0, lines, 40 * int(lines))  # noqa: E731
    # dense ties: the floor, a whole number of segments: 30 segments on 3000 lines, 60 on 6000
    assert auto_knot_lines(3000.0, dense(3000), 200_000) == pytest.approx(100.0)
    assert auto_knot_lines(6000.0, dense(6000), 200_000) == pytest.approx(100.0)
    # a 40 000-line scene: the knot cap (the count, not the spacing, is bounded)
    s = auto_knot_lines(40_000.0, dense(400), 200_000)
    assert s >= 40_000.0 / (MAX_AUTO_KNOTS - 3) and 40_000.0 / s + 3 <= MAX_AUTO_KNOTS
    # sparse ties: >= 20 measurements per segment over the lines they cover
    assert auto_knot_lines(3000.0, np.linspace(0, 3000, 300), 600) == pytest.approx(200.0)
    # a huge block: the Jacobian's memory bound widens the spacing
    assert auto_knot_lines(3000.0, dense(3000), 50_000_000) == pytest.approx(3000.0)
    assert auto_knot_lines(3000.0, dense(3000), 200_000) >= FLOOR_KNOT_LINES


def test_knot_bounds_name_the_option():
    bias = JitterBias((0.0, 3000.0), 1.0)
    with pytest.raises(AdjustmentError, match="--jitter-knot-lines.*measurements support"):
        check_knots("left", bias, 5000, 10_000)
    with pytest.raises(AdjustmentError, match=f"more than the solver can hold \\({MAX_KNOTS}"):
        check_knots("left", bias, 10**6, 10**6)
    with pytest.raises(AdjustmentError, match="GiB of Jacobian"):
        check_knots("left", JitterBias((0.0, 3000.0), 10.0), 10**8, 10**8)
    check_knots("left", JitterBias((0.0, 3000.0), 100.0), 10**5, 10**5)  # fits
