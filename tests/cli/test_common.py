"""``jaxgeo.cli._common``: what every sub-command shares."""

import warnings

from jaxgeo.cli._common import ours
from jaxgeo.errors import JaxgeoWarning


def test_only_jaxgeo_warnings_become_the_commands_lines():
    """A library's notice (numpy 2.5 made rasterio's reprojection warn ``DeprecationWarning``
    on a GPU machine's image: printed as ``jaxgeo coregister: warning:`` lines) goes back to
    Python's filters; jaxgeo's own are kept, in order."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.warn("a library's notice", DeprecationWarning, stacklevel=1)
        warnings.warn("the DEM has voids", JaxgeoWarning, stacklevel=1)
        warnings.warn("mean of empty slice", RuntimeWarning, stacklevel=1)
        warnings.warn("the adjustment did not converge", JaxgeoWarning, stacklevel=1)
    with warnings.catch_warnings(record=True) as again:
        warnings.simplefilter("always")
        kept = ours(caught)
    kept = [str(w.message) for w in kept]
    assert kept == ["the DEM has voids", "the adjustment did not converge"]
    assert [(w.category, str(w.message)) for w in again] == [
        (DeprecationWarning, "a library's notice"),
        (RuntimeWarning, "mean of empty slice"),
    ]
    with warnings.catch_warnings(record=True) as hidden:  # Python's default filters
        warnings.resetwarnings()
        warnings.simplefilter("ignore", DeprecationWarning)
        ours(caught[:1])
    assert hidden == []


def test_called_inside_the_recording_block_it_ends():
    """Re-issued inside ``catch_warnings(record=True)``, a warning joins the list being read:
    ``jaxgeo ortho`` looped on it, allocating until the OOM killer came (18 GB)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.warn("a library's notice", DeprecationWarning, stacklevel=1)
        assert ours(caught) == []
    assert [str(w.message) for w in caught] == ["a library's notice"] * 2


def test_an_unknown_image_is_refused_with_the_names_accepted():
    """``--model IMG=FILE`` / ``--image-origin IMG=COL,ROW``: IMG is the path as given, the
    file name or the stem; an IMG naming no image gets them all in the message."""
    import pytest

    from jaxgeo.cli import CommandError
    from jaxgeo.cli._inputs import _by_image

    images = ["data/left.tif", "data/right.tif"]
    for key in ("data/left.tif", "left.tif", "left"):
        assert _by_image([f"{key}=m.json"], images, "--model") == {"data/left.tif": "m.json"}
    with pytest.raises(CommandError) as err:
        _by_image(["lfet=m.json"], images, "--model")
    message = str(err.value)
    assert message.startswith("--model 'lfet=m.json': expected IMG=FILE with IMG one of the images")
    assert "path, file name or stem" in message
    assert "data/left.tif (left.tif, left); data/right.tif (right.tif, right)" in message
    with pytest.raises(CommandError, match=r"IMG=COL,ROW .*: data/left.tif \(left.tif, left\)"):
        _by_image(["x=1,2"], images, "--image-origin")
    with pytest.raises(CommandError, match="image data/left.tif given twice"):
        _by_image(["left=a", "left.tif=b"], images, "--model")
    assert _by_image(["m.json"], images[:1], "--model") == {"data/left.tif": "m.json"}


def test_library_parameter_names_become_options():
    from jaxgeo.cli import _one_line
    from jaxgeo.cli._common import name_options

    options = {"tolerance_m": "--tolerance", "nmad_k": "--nmad-k"}
    assert name_options("tolerance_m -1: expected > 0", options) == "--tolerance -1: expected > 0"
    # whole words only, and only the names given
    assert name_options("tolerance_mm nmad_k 0", options, ["nmad_k"]) == "tolerance_mm --nmad-k 0"
    err = ValueError("dem.tif: a geoid only applies to orthometric heights (height='orthometric')")
    assert _one_line(err).endswith("(--dem-height orthometric)")


def test_exit_codes_epilog_ends_with_the_conventions_page():
    from jaxgeo.cli._common import SEE_CONVENTIONS, exit_codes

    text = exit_codes({1: "not converged"})
    assert text.startswith("exit status:\n    0  done\n    1  not converged\n")
    assert text.endswith("\n\n" + SEE_CONVENTIONS) and "docs/cli-conventions.md" in text
