"""A second ``jaxgeo ortho`` in a new process with the same ``JAXGEO_CACHE_DIR`` traces nothing:
the per-tile kernels and the plan's localisations are kept programs, loaded from the cache (the
fixed cost of a small product: issue 54, item 4), and jax lowers and compiles nothing either
(no eager jax operation: each was a program lowered in every process)."""

import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import rasterio

from tests.ortho.conftest import ventoux_dem_ellipsoidal  # noqa: F401

REPO = pathlib.Path(__file__).resolve().parents[2]

# runs ``jaxgeo ortho`` in this process, counting the programs traced: the kept programs
# exported (``_export`` traces them) and any call that falls back to plain jit (traced again in
# every process), as tests/models/test_rpc_fit.py counts them; and every program jax traces,
# lowers or compiles (its monitoring events: an eager ``jnp`` operation is one such program)
RUN = """
import json, sys
import jax
from jaxgeo._runtime import exported
traced, plain, lowered = [], [], []
STEPS = ("jaxpr_trace_duration", "jaxpr_to_mlir_module_duration", "backend_compile_duration")
jax.monitoring.register_event_duration_secs_listener(
    lambda event, secs, **kw: event.endswith(STEPS) and lowered.append(event)
)
real_export, real_jit, real_apart = exported._export, exported._filter_jit, exported._compiled_call
exported._export = lambda fn, *a: traced.append(fn.__qualname__) or real_export(fn, *a)
exported._filter_jit = lambda fn: plain.append(fn.__qualname__) or real_jit(fn)
exported._compiled_call = (
    lambda fn, *a, **k: plain.append(fn.__qualname__) or real_apart(fn, *a, **k)
)
from jaxgeo.cli import entry
sys.argv = ["jaxgeo", *sys.argv[1:]]
try:
    entry()
except SystemExit as stop:
    assert not stop.code, stop.code
with open(OUT, "w") as f:
    json.dump({"traced": traced, "plain": plain, "lowered": len(lowered)}, f)
"""


def _run(tmp_path, cache, name, image, model, dem):
    env = dict(os.environ, JAXGEO_CACHE_DIR=str(cache), PYTHONPATH=str(REPO))
    record = tmp_path / f"{name}.json"
    out = tmp_path / f"{name}.tif"
    script = RUN.replace("OUT", repr(str(record)))
    args = ["ortho", str(image), "--model", f"left_image={model}", "--dem", str(dem),
            "--res", "2", "-o", str(out), "--quiet"]  # fmt: skip
    run = subprocess.run([sys.executable, "-c", script, *args], env=env, cwd=REPO,
                         capture_output=True, text=True, timeout=600)  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    with rasterio.open(out) as ds:
        return json.loads(record.read_text()), ds.read()


def test_a_second_run_in_a_new_process_traces_nothing(real_data, ventoux_dem_ellipsoidal,  # noqa: F811
                                                       tmp_path):  # fmt: skip
    image = real_data / "ventoux" / "left_image.tif"
    model = real_data / "phr_ventoux__left_image.geom"
    cache = tmp_path / "cache"
    first, product = _run(tmp_path, cache, "first", image, model, ventoux_dem_ellipsoidal)
    # the tile's two kernels and the plan's programs, each traced once
    assert {"map_pixels", "sample_window", "_at_height", "_dem_height"} <= set(first["traced"])
    assert len(first["traced"]) == len(set(first["traced"]))
    assert first["plain"] == [] and first["lowered"] > 0
    again, same = _run(tmp_path, cache, "again", image, model, ventoux_dem_ellipsoidal)
    # every program loaded, none traced, and nothing else lowered or compiled
    assert again == {"traced": [], "plain": [], "lowered": 0}
    np.testing.assert_array_equal(same, product)
    assert (product > 0).mean() > 0.5
