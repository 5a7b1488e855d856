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
