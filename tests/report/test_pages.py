"""The HTML reports: their figures per section (each a decodable PNG sized for a screen), self-
contained (no script, link or remote source), written atomically and never over a file without
``overwrite``; the figures' content where it can be checked (the hillshade's light)."""

import numpy as np
import pytest

from tests.report.conftest import png_size, sections

EXPECTED = {
    "adjust": {"Ground control and check points": 1, "Residual histograms": 1,
               "Residuals per image": 2, "Summary": 0, "Before and after": 0},
    "dsm": {"Relief": 1, "Where the heights come from": 1, "Height uncertainty": 1},
    "ortho": {"Quicklook": 1},
    "coreg": {"DSM - REF before and after": 2},
}  # fmt: skip


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_figures_per_section(pages, name):
    page = sections(pages[name])
    assert not page.forbidden, page.forbidden  # nothing fetched, nothing run
    for heading, count in EXPECTED[name].items():
        assert len(page.sections.get(heading, [])) == count, (heading, page.sections.keys())
    for src in (s for srcs in page.sections.values() for s in srcs):
        width, height = png_size(src)
        assert width == 900 and 250 <= height <= 1000, (width, height)


def test_adjustment_page_holds_the_results_numbers(pages):
    text = pages["adjust"].read_text()
    # the demo block: tens of metres before (direct georeferencing), < 1.3 m after
    assert "direct" in text and "check RMS north (m)" in text
    assert "fore: RMS row (px)" in text and "aft: residual vectors" in text
    assert text.count("<table>") >= 2


def test_no_overwrite_without_overwrite(pages):
    from jaxgeo.report import write_dsm_report

    path = pages["dsm"]
    before, inode = path.read_bytes(), path.stat().st_ino
    with pytest.raises(FileExistsError, match="dsm.report.html"):
        write_dsm_report(path.with_name("dsm.tif"), path)
    assert path.read_bytes() == before
    write_dsm_report(path.with_name("dsm.tif"), path, overwrite=True)
    assert path.stat().st_ino != inode  # a new file renamed into place (atomic), not rewritten
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".dsm.report")]


def test_report_beside_names_the_product():
    from jaxgeo.report import report_beside

    assert report_beside("/a/b/dsm_d1.tif").as_posix() == "/a/b/dsm_d1.report.html"


def test_hillshade_lit_from_the_north_west():
    from jaxgeo.report._raster import hillshade

    cols = np.arange(50.0)
    facing_east = np.tile(-cols, (50, 1))  # heights fall to the east (45°)
    facing_west = -facing_east
    flat = np.zeros((50, 50))
    w, e, f = (hillshade(z, 1.0)[5:-5, 5:-5].mean() for z in (facing_west, facing_east, flat))
    assert w > f > e  # a slope towards the light is brighter than flat ground, away darker
    assert np.isclose(f, np.sin(np.radians(45.0)))
    assert np.isclose(w, (0.5 + np.sqrt(0.5)) / np.sqrt(2.0))  # n . light, by hand
    facing_north = np.tile(np.arange(50.0)[:, None], (1, 50))  # rows go south: rises southwards
    assert hillshade(facing_north, 1.0).mean() > f


def test_coregistration_page_with_a_dem_reference(pages, tmp_path):
    """REF given as a DEM (read_dem: its height reference applied), as ``coregister
    --dem-height/--geoid`` gives it: heights sampled per cell, NaN outside it (no error)."""
    from jaxgeo.coreg import coregister
    from jaxgeo.io import read_dem
    from jaxgeo.report import write_coregistration_report

    w = pages["coreg"].parent
    ref = read_dem(w / "ref.tif")
    result = coregister(w / "moved.tif", ref, tmp_path / "aligned.tif")
    path = write_coregistration_report(result, w / "moved.tif", ref, tmp_path / "a.html")
    assert len(sections(path).sections["DSM - REF before and after"]) == 2
    assert "ref.tif" in path.read_text()
