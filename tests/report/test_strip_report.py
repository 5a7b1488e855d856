"""The strip's page (``jaxgeo strip --report``): the whole strip per stage, a summary plot per
sub-scene, the ground points, and in detail only the worst sub-scenes (a page that stays
readable at 80). A 4-scene simulated strip (seed 2), adjusted once: ~30 s on the shared
2-core machine, the adjustment's."""

import warnings

import pytest

from jaxgeo.simulate import carto2s_strip
from tests.report.conftest import png_size, sections


@pytest.fixture(scope="module")
def strip_run(tmp_path_factory):
    from jaxgeo.strip import adjust_strip_files

    d = tmp_path_factory.mktemp("strip4")
    carto2s_strip(4, seed=2).save(d)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (a short strip's GCP distribution: warned, not here)
        return adjust_strip_files(d)


def test_strip_page(strip_run, tmp_path, monkeypatch):
    from jaxgeo.report import _adjustment, write_strip_report

    monkeypatch.setattr(_adjustment, "DETAILED_SCENES", 2)
    path = write_strip_report(strip_run, tmp_path / "report.html")
    page = sections(path)
    assert not page.forbidden
    assert len(page.sections["Per sub-scene"]) == 2  # per scene, per pair
    assert len(page.sections["Ground control and check points"]) == 1
    assert len(page.sections["Residuals per image"]) == 2  # the 2 worst of 4 only
    for srcs in page.sections.values():
        for src in srcs:
            assert png_size(src)[0] == 900
    text = path.read_text()
    for stage in ("direct", "level1", "level2"):
        assert f"<td>{stage}</td>" in text
