"""The persistent compilation cache is set up when jaxgeo is imported (fresh interpreters:
jax reads the settings when it starts)."""

import json
import os
import pathlib
import subprocess
import sys

REPO = pathlib.Path(__file__).resolve().parents[1]
PROBE = (
    "import json, jaxgeo, jax; jax.jit(lambda x: x + 1)(1.0).block_until_ready(); "
    "print(json.dumps({'dir': jax.config.jax_compilation_cache_dir, "
    "'x64': jax.config.jax_enable_x64, "
    "'min_s': jax.config.jax_persistent_cache_min_compile_time_secs, "
    "'xla_flags': __import__('os').environ.get('XLA_FLAGS')}))"
)


def _probe(tmp_path, **env):
    # the suite itself runs with the cache off (tests/conftest.py): the probe starts clean
    drop = ("JAX_COMPILATION_CACHE_DIR", "JAXGEO_CACHE_DIR")
    full = {k: v for k, v in os.environ.items() if k not in drop}
    full.update(env, PYTHONPATH=str(REPO), XDG_CACHE_HOME=str(tmp_path / "xdg"))
    run = subprocess.run(
        [sys.executable, "-c", PROBE], env=full, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_cache_on_by_default_in_the_user_cache_dir(tmp_path):
    out = _probe(tmp_path)
    assert out["dir"] == str(tmp_path / "xdg" / "jaxgeo" / "jax")
    assert out["x64"] and out["min_s"] == 0.0
    assert any((tmp_path / "xdg" / "jaxgeo" / "jax").glob("*-cache"))  # the program is cached


def test_512_bit_vectors_unless_the_user_chose_a_width(tmp_path):
    assert _probe(tmp_path, XLA_FLAGS="")["xla_flags"] == "--xla_cpu_prefer_vector_width=512"
    mine = "--xla_cpu_prefer_vector_width=256 --xla_cpu_multi_thread_eigen=false"
    assert _probe(tmp_path, XLA_FLAGS=mine)["xla_flags"] == mine


def test_cache_dir_overridable_and_off(tmp_path):
    assert _probe(tmp_path, JAXGEO_CACHE_DIR=str(tmp_path / "c"))["dir"] == str(tmp_path / "c")
    out = _probe(tmp_path, JAXGEO_CACHE_DIR="off")
    assert out["dir"] is None and out["x64"]


def test_a_users_own_jax_cache_dir_is_kept(tmp_path):
    out = _probe(tmp_path, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "mine"))
    assert out["dir"] == str(tmp_path / "mine")


def test_a_child_of_a_jaxgeo_process_keeps_its_own_setting(tmp_path):
    """jaxgeo exports jax's cache variables before jax starts; a child process inherits them
    and must still follow its own ``JAXGEO_CACHE_DIR`` (a directory, or ``off``)."""
    parent = (
        "import json, os, subprocess, sys, jaxgeo\n"
        "out = {}\n"
        "for value in (sys.argv[1], 'off'):\n"
        "    env = dict(os.environ, JAXGEO_CACHE_DIR=value)\n"
        f"    run = subprocess.run([sys.executable, '-c', {PROBE!r}], env=env,\n"
        "                         capture_output=True, text=True, check=True)\n"
        "    out[value] = json.loads(run.stdout.strip().splitlines()[-1])['dir']\n"
        "print(json.dumps(out))\n"
    )
    drop = ("JAX_COMPILATION_CACHE_DIR", "JAXGEO_CACHE_DIR")
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env.update(PYTHONPATH=str(REPO), XDG_CACHE_HOME=str(tmp_path / "xdg"))
    child = str(tmp_path / "child")
    run = subprocess.run(
        [sys.executable, "-c", parent, child], env=env, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout.strip().splitlines()[-1]) == {child: child, "off": None}
