"""The persistent compilation cache is set up when jaxgeo is imported (fresh interpreters:
jax reads the settings when it starts)."""

import json
import os
import pathlib
import shutil
import subprocess
import sys

import pytest

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


DEVICES = "import json, jaxgeo, jax; print(json.dumps(len(jax.local_devices(backend='cpu'))))"


def _devices(taskset: str | None = None, drop=(), **env) -> int:
    """The CPU devices (on a GPU machine too) of a fresh interpreter that imports jaxgeo first,
    without the suite's own XLA flags (a user's environment) unless ``env`` gives some."""
    full = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", *drop)}
    full = {k: v for k, v in full.items() if not k.startswith(("JAXGEO_CPU", "JAX_NUM_CPU"))}
    full.update(env, PYTHONPATH=str(REPO), JAXGEO_CACHE_DIR="off")
    cmd = [sys.executable, "-c", DEVICES]
    if taskset is not None:
        cmd = ["taskset", "-c", taskset, *cmd]
    run = subprocess.run(cmd, env=full, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_one_cpu_device_per_usable_core():
    assert _devices() == len(os.sched_getaffinity(0))
    first = sorted(os.sched_getaffinity(0))[0]
    if shutil.which("taskset"):
        assert _devices(taskset=str(first)) == 1  # pinned to one core: jax's single device


def test_device_count_set_by_the_user_or_single_threaded_is_kept():
    assert _devices(JAXGEO_CPU_DEVICES="3") == 3
    assert _devices(JAXGEO_CPU_DEVICES="1") == 1
    assert _devices(JAXGEO_CPU_DEVICES="many") == 1  # not a number: the safe single device
    assert _devices(JAX_NUM_CPU_DEVICES="3") == 3
    assert _devices(XLA_FLAGS="--xla_force_host_platform_device_count=3") == 3
    # the test suite's flags (tests/conftest.py): one thread asked for, one device given
    assert _devices(XLA_FLAGS="--xla_cpu_multi_thread_eigen=false", JAXGEO_CPU_DEVICES="") == 1


def test_the_suite_runs_on_one_device():
    """tests/conftest.py asks XLA for a single thread; the suite's results are one device's."""
    import jax

    assert jax.local_device_count() == 1


def test_a_child_counts_its_own_cores():
    """jaxgeo exports ``JAX_NUM_CPU_DEVICES`` for jax to read; a child process pinned to one core
    must not inherit its parent's count."""
    if not shutil.which("taskset") or len(os.sched_getaffinity(0)) < 2:
        pytest.skip("needs taskset and two usable cores")
    first = sorted(os.sched_getaffinity(0))[0]
    parent = (
        "import json, subprocess, sys, jaxgeo\n"
        f"cmd = ['taskset', '-c', '{first}', sys.executable, '-c', {DEVICES!r}]\n"
        "print(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env.update(PYTHONPATH=str(REPO), JAXGEO_CACHE_DIR="off", JAXGEO_CPU_DEVICES="")
    run = subprocess.run(
        [sys.executable, "-c", parent], env=env, capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout.strip().splitlines()[-1]) == 1
