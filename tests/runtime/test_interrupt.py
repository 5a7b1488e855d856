"""An interruption whose ``KeyboardInterrupt`` Python drops (raised inside a garbage-collector
callback: "Exception ignored in ...") still ends the command with status 130 and no output."""

import os
import subprocess
import sys
import textwrap

import pytest

from jaxgeo._runtime import interrupt as _interrupt
from jaxgeo.io.internal import atomic_output


@pytest.fixture
def requested():
    _interrupt.request()
    yield
    _interrupt.reset()


def test_nothing_is_committed_once_an_interruption_was_requested(tmp_path, requested):
    out = tmp_path / "out.txt"
    with pytest.raises(KeyboardInterrupt):
        with atomic_output(out) as tmp:
            tmp.write_text("partial")
    assert list(tmp_path.iterdir()) == []  # neither the output nor the temporary file


def test_without_a_request_the_output_is_committed(tmp_path):
    with atomic_output(tmp_path / "out.txt") as tmp:
        tmp.write_text("done")
    assert (tmp_path / "out.txt").read_text() == "done"


# SIGINT sent from a gc callback: its handler runs inside the callback, where Python drops the
# KeyboardInterrupt ("Exception ignored in: <function ...>") and goes on with the command (jax's
# own gc callback is where a real Ctrl-C was lost in CI).
CHILD = textwrap.dedent(
    """
    import gc, os, signal, sys
    import jax, jaxgeo.cli._simulate, jaxgeo.simulate  # the interruption lands in the computation
    from jaxgeo import cli

    # jax's backends started first: it initialises every installed plugin (CUDA's too, whatever
    # JAX_PLATFORMS says) under a bare `except:` that logs an interruption and drops it
    jax.devices()

    sent = []

    def callback(phase, info):
        armed = signal.getsignal(signal.SIGINT) is cli._interrupt_handler
        if phase == "start" and not sent and armed:
            sent.append(1)
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(10000):  # the Python handler runs here, inside the callback
                pass

    gc.callbacks.append(callback)
    sys.argv = ["jaxgeo", "simulate", "cartosat1", "-o", sys.argv[1]]
    cli.entry()
    """
)


@pytest.mark.parametrize("redeliver", [True, False])
def test_an_interruption_lost_in_a_gc_callback_still_ends_the_command(tmp_path, redeliver):
    out = tmp_path / "scene"
    child = CHILD
    if not redeliver:  # the last line of defence alone: atomic_output commits nothing
        plain = "cli._redeliver_lost_interrupt = lambda u, previous=sys.unraisablehook: previous(u)"
        child = child.replace("cli.entry()", f"{plain}\ncli.entry()")
    # on the CPU; a GPU machine's CUDA plugin starts all the same (the child starts jax first)
    env = {**os.environ, "JAXGEO_TYPECHECK": "0", "JAX_PLATFORMS": "cpu"}
    proc = subprocess.run([sys.executable, "-c", child, str(out)], capture_output=True, text=True,
                          env=env, timeout=300)  # fmt: skip
    assert proc.returncode == 130, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines()[-1] == (
        "jaxgeo simulate: interrupted; no output was written"
    )
    if redeliver:
        assert "Exception ignored" not in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists() or list(out.iterdir()) == []
