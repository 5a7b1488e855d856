"""Tie points formed from known line offsets (003_ section 8)."""

import numpy as np
import pytest

from jaxgeo.strip._delivery import SubScene
from jaxgeo.strip._ties import overlap_lines, strip_ties


def _strip(n=5, rows=1000, step=900, cols=800):
    return [SubScene(f"s{k}", k * step, rows, cols) for k in range(n)]


@pytest.mark.parametrize("seed", [None, 3])
def test_ties_are_the_same_strip_pixel_in_both_scenes(seed):
    scenes = _strip()
    ties = strip_ties(scenes, per_pair=50, seed=seed)
    assert ties.n_ties == 4 * 50
    assert len(ties.point) == 2 * ties.n_ties
    for t in range(ties.n_ties):
        rows = np.flatnonzero(ties.point == t)
        (i, j) = ties.scene[rows]
        assert j == i + 1 == ties.pair[t] + 1
        strip_line = [
            ties.xy[r, 1] + scenes[s].line_offset
            for r, s in zip(rows, ties.scene[rows], strict=True)
        ]
        assert strip_line[0] == strip_line[1]
        assert ties.xy[rows[0], 0] == ties.xy[rows[1], 0]
        # inside both scenes, in the overlap
        for r, s in zip(rows, ties.scene[rows], strict=True):
            assert 0 <= ties.xy[r, 1] <= scenes[s].n_rows - 1
            assert 0 <= ties.xy[r, 0] <= scenes[s].n_cols - 1
        first, last = overlap_lines(scenes[i], scenes[j])
        assert first <= strip_line[0] <= last


def test_grid_density_is_configurable():
    few = strip_ties(_strip(3), per_pair=6)
    many = strip_ties(_strip(3), per_pair=200)
    assert few.n_ties == 12 and many.n_ties == 400
    # the grid spans the overlap in both directions
    xs = many.xy[many.scene == 0, 0]
    assert xs.min() < 10 and xs.max() > 790


def test_no_overlap_is_an_error_naming_the_pair():
    scenes = [SubScene("a", 0, 100, 50), SubScene("b", 100, 100, 50)]
    with pytest.raises(ValueError, match="'a' and 'b' do not overlap"):
        strip_ties(scenes)
    with pytest.raises(ValueError, match="at least two"):
        strip_ties(scenes[:1])
