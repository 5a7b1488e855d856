"""The one progress facility (:mod:`jaxgeo._runtime.progress`): plain lines with percent, rate and
ETA off a terminal (sparse: every ~10 % or ~30 s), a bar on one, nothing when disabled or silenced
(``--quiet``); and the commands: ``--quiet`` prints nothing on stderr, progress lines without it,
``--json``'s stdout one JSON object."""

import io
import json
import re
import shutil

import pytest

from jaxgeo._runtime import progress as pg
from jaxgeo.cli import main
from jaxgeo.simulate import demo_dir


class Clock:
    """``time.monotonic`` of the module, moved by hand."""

    def __init__(self, monkeypatch):
        self.t = 1000.0
        monkeypatch.setattr(pg.time, "monotonic", lambda: self.t)


class Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture(autouse=True)
def _not_silenced():
    pg.silence(False)
    yield
    pg.silence(False)


def test_plain_lines_every_tenth_with_percent_rate_and_eta(monkeypatch):
    clock, out = Clock(monkeypatch), io.StringIO()
    with pg.Progress("tiles", 40, "tile", file=out) as bar:
        for _ in range(40):
            clock.t += 0.5  # 2 tiles/s
            bar.update()
    text = out.getvalue()
    lines = text.splitlines()
    assert "\r" not in text
    assert lines[0] == "tiles: 0/40 tile (0 %), elapsed 0:00"
    # one at the start, one each 10 % (4 tiles), none repeated at the end
    assert len(lines) == 11, lines
    assert lines[1] == "tiles: 4/40 tile (10 %), 2 tile/s, elapsed 0:02, ETA 0:18"
    assert lines[5] == "tiles: 20/40 tile (50 %), 2 tile/s, elapsed 0:10, ETA 0:10"
    assert lines[-1] == "tiles: 40/40 tile (100 %), 2 tile/s, elapsed 0:20, done"


def test_a_slow_step_still_shows_a_line_every_30_s(monkeypatch):
    clock, out = Clock(monkeypatch), io.StringIO()
    bar = pg.Progress("pairs", 1000, "pair", file=out)
    for k in range(1, 6):
        clock.t += 40.0  # 0.5 % of the total a step, 40 s each
        bar.update()
        assert len(out.getvalue().splitlines()) == 1 + k
    assert out.getvalue().splitlines()[-1].startswith("pairs: 5/1000 pair (0 %), 40 s/pair")
    assert "ETA 11:03:20" in out.getvalue().splitlines()[-1]  # 995 pairs at 40 s
    bar.close()
    assert len(out.getvalue().splitlines()) == 6  # the last count was shown already


def test_the_rate_leaves_out_the_first_steps_start_up(monkeypatch):
    clock, out = Clock(monkeypatch), io.StringIO()
    bar = pg.Progress("dsm", 10, "tile", file=out)
    clock.t += 20.0  # the first tile compiles
    bar.update()
    assert out.getvalue().splitlines()[-1] == (
        "dsm: 1/10 tile (10 %), 20 s/tile, elapsed 0:20, ETA 3:00"
    )  # one step: all there is to go by
    for _ in range(4):
        clock.t += 2.0
        bar.update()
    # 4 tiles in 8 s after the first, not 5 in 28 s: 10 s left for 5 tiles, not 28
    assert out.getvalue().splitlines()[-1] == (
        "dsm: 5/10 tile (50 %), 2 s/tile, elapsed 0:28, ETA 0:10"
    )


def test_a_note_before_the_total_restarts_the_rate_clock(monkeypatch):
    clock, out = Clock(monkeypatch), io.StringIO()
    bar = pg.Progress("pair 1/2", None, "band", file=out)
    bar.note("tie points")
    clock.t += 100.0  # the tie points and the rectification: no band yet
    bar.note("SGM over [-15, 18] px")  # the counted stage starts
    clock.t += 2.0
    bar.set(1, 10)
    clock.t += 2.0
    bar.set(2)
    clock.t += 2.0
    bar.set(3)
    bar.close()
    last = out.getvalue().splitlines()[-1]
    # 3 bands in 6 s since the last note before them (not in 106 s): 14 s left for 7 bands
    assert last == ("pair 1/2: 3/10 band (30 %), 2 s/band, elapsed 1:46, ETA 0:14 -- SGM "
                    "over [-15, 18] px")  # fmt: skip


def test_disabled_and_silenced_write_nothing():
    out = io.StringIO()
    with pg.Progress("x", 3, enabled=False, file=out) as bar:
        bar.update(3)
        bar.note("stage")
        bar.say("a line")
    pg.silence(True)  # the command line's --quiet: whatever a library default says
    assert pg.silenced()
    with pg.Progress("x", 3, file=out) as bar:
        bar.update(3)
        bar.say("a line")
    pg.say("[dsm] rasterising", file=out)
    assert out.getvalue() == ""
    pg.silence(False)
    pg.say("[dsm] rasterising", file=out)
    assert out.getvalue() == "[dsm] rasterising\n"


def test_a_terminal_gets_a_bar_with_eta():
    out = Terminal()
    with pg.Progress("ortho", 5, "tile", file=out) as bar:
        bar.note("writing")
        bar.update(5)
    text = out.getvalue()
    assert "\r" in text and "ortho: 100%" in text and "5/5" in text and "writing" in text
    assert re.search(r"\[\d+:\d\d<\d+:\d\d", text), text  # tqdm's elapsed<remaining
    out = Terminal()
    with pg.Progress("pair 1/1", None, "band", file=out) as bar:  # the bands' count comes later
        bar.note("SGM over [-15, 18] px")
        bar.set(1, 4)
        bar.set(4)
    assert "pair 1/1: 100%" in out.getvalue() and "4/4" in out.getvalue()


def test_stages_say_the_time_so_far_and_of_the_last_step(monkeypatch):
    clock, lines = Clock(monkeypatch), []
    stages = pg.Stages(lines.append)
    stages("solving: 100 observations")
    clock.t += 65.0
    stages("snooping round 1: removing 1, re-solving")
    clock.t += 5.0
    stages.done("solved (1 snooping round)")
    assert lines == [
        "solving: 100 observations",
        "snooping round 1: removing 1, re-solving [1:05 so far, the last step 1:05]",
        "solved (1 snooping round) in 1:10",
    ]
    silent = pg.Stages(None)
    silent("x")
    silent.done("y")  # no callback: nothing, no error


# --- the commands: stderr is a pipe here (pytest captures it), so plain lines -----------------
# (each test runs its command twice, --quiet and not: some 20 s on 2 loaded cores, most of it the
# first run's compilation)


@pytest.fixture(scope="module")
def stereo_scene(tmp_path_factory):
    """A small simulated pair (256 px), for match and dsm."""
    out = tmp_path_factory.mktemp("progress") / "scene"
    assert main(["simulate", "stereo-scene", "--size", "256", "--seed", "3", "-o", str(out),
                 "--quiet"]) == 0  # fmt: skip
    return out


def _run(capsys, argv):
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _percent_and_eta(err: str, name: str) -> list[str]:
    lines = [ln for ln in err.splitlines() if ln.startswith(f"{name}: ")]
    assert lines, err
    assert "\r" not in err  # log-friendly: no carriage returns off a terminal
    assert any(re.search(r"\(\d+ %\), .*ETA \d+:\d\d", ln) for ln in lines), err
    return lines


def test_match_quiet_progress_and_json(stereo_scene, tmp_path, capsys):
    images = [str(stereo_scene / "left.tif"), str(stereo_scene / "right.tif")]
    argv = ["match", *images, "-o"]
    code, out, err = _run(capsys, [*argv, str(tmp_path / "q.csv"), "--quiet"])
    assert code == 0 and err == ""
    code, out, err = _run(capsys, [*argv, str(tmp_path / "p.csv"), "--json"])
    assert code == 0
    json.loads(out)  # one object, nothing else on stdout
    assert len(out.strip().splitlines()) == 1
    lines = _percent_and_eta(err, "match")
    assert lines[-1].startswith("match: 3/3 step (100 %)"), lines  # 2 images' SIFT, 1 pair


def test_dsm_quiet_progress_and_json(stereo_scene, tmp_path, capsys):
    # bands of 64 rows: a count of several bands to show
    argv = ["dsm", str(stereo_scene / "left.tif"), str(stereo_scene / "right.tif"), "--res", "4",
            "--band-rows", "64", "-o"]  # fmt: skip
    code, out, err = _run(capsys, [*argv, str(tmp_path / "q.tif"), "--quiet"])
    assert code == 0 and err == "", err
    code, out, err = _run(capsys, [*argv, str(tmp_path / "p.tif"), "--json"])
    assert code == 0, err
    assert len(out.strip().splitlines()) == 1 and json.loads(out)["ok"] is True
    _percent_and_eta(err, "pair 1/1")  # the dense-matching bands of the pair


def test_adjust_quiet_timed_stages_and_json(tmp_path, capsys):
    scene = tmp_path / "in"
    shutil.copytree(demo_dir(), scene)
    argv = ["adjust", "--image", f"fore={scene / 'fore.txt'}", "--image",
            f"aft={scene / 'aft.txt'}", "--ground", str(scene / "ground.csv"),
            "--observations", str(scene / "observations.csv"), "--bias", "shift"]  # fmt: skip
    code, out, err = _run(capsys, [*argv, "--quiet", "-o", str(tmp_path / "q")])
    assert code == 0 and err == "", err
    assert not pg.silenced()  # --quiet was the run's own: the process is not left silenced
    code, out, err = _run(capsys, [*argv, "--json", "-o", str(tmp_path / "p")])
    assert code == 0, err
    assert len(out.strip().splitlines()) == 1 and json.loads(out)["converged"]
    assert "jaxgeo adjust: solving: " in err
    assert re.search(r"jaxgeo adjust: solved \(\d+ snooping rounds?\) in \d+:\d\d", err), err
