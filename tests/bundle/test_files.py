"""``adjust_files``: the direct georeferencing beside the adjustment starts once the solve is
traced (the trace holds the GIL, XLA's compilation does not), and not at all after an error."""

import pytest

import jaxgeo.bundle._files as files
from jaxgeo._runtime import exported as _exported
from jaxgeo.simulate import demo_dir


def _demo():
    d = demo_dir()
    return {"fore": d / "fore.txt", "aft": d / "aft.txt"}, d / "observations.csv", d / "ground.csv"


def test_direct_georeferencing_starts_once_the_solve_is_traced(monkeypatch):
    events = []
    real_traced, real_direct = _exported._solve_traced, files.direct_georeferencing

    def traced():
        events.append("solve traced")
        real_traced()

    def direct(*args, **kwargs):
        events.append("direct")
        return real_direct(*args, **kwargs)

    monkeypatch.setattr(_exported, "_solve_traced", traced)
    monkeypatch.setattr(files, "direct_georeferencing", direct)
    images, obs, ground = _demo()
    run = files.adjust_files(images, obs, ground, bias="shift", direct_roles=("check",))
    assert events[:2] == ["solve traced", "direct"]
    assert run.direct is not None and len(run.direct.ids) == 60
    assert run.result.converged


def test_no_direct_georeferencing_after_an_adjustment_error(monkeypatch):
    called = []
    monkeypatch.setattr(files, "direct_georeferencing", lambda *a, **k: called.append(1))

    def fail(*args, **kwargs):
        raise ValueError("the adjustment failed")

    monkeypatch.setattr(files, "adjust", fail)
    images, obs, ground = _demo()
    with pytest.raises(ValueError, match="the adjustment failed"):
        files.adjust_files(images, obs, ground, bias="shift")
    assert called == []


def test_when_solve_traced_is_per_block_and_thread():
    calls = []
    with _exported.when_solve_traced(lambda: calls.append("outer")):
        _exported._solve_traced()
        with _exported.when_solve_traced(lambda: calls.append("inner")):
            _exported._solve_traced()
        _exported._solve_traced()
    _exported._solve_traced()  # outside: nothing
    assert calls == ["outer", "inner", "outer"]
