"""jaxgeo._runtime.shard.shard_map: zero-size inputs made inside the mapped call, the results
those of the unmapped function. Over two CPU devices in a subprocess (the device count is fixed
when jax starts; jaxlib 0.11.2 killed the process compiling this program before, on two devices
only)."""

import json
import os
import pathlib
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np

from jaxgeo._runtime.shard import shard_map

REPO = pathlib.Path(__file__).resolve().parents[1]

SCRIPT = """
import json
import jax, jax.numpy as jnp, numpy as np
import jaxgeo
from jaxgeo._runtime.shard import shard_map

P = jax.sharding.PartitionSpec
mesh = jax.sharding.Mesh(np.array(jax.local_devices()[:2]), ("r",))

def body(fixed, batch):
    # every input used, the zero-size ones too (a sum of nothing, a concatenation)
    w, empty = fixed["w"], fixed["empty"]
    x, none_col = batch
    y = x * w + jnp.sum(empty) + jnp.sum(none_col)
    return jnp.concatenate([y, none_col * 2.0], axis=1), empty.shape[0] + jnp.zeros(x.shape[0])

fixed = {"w": jnp.arange(3.0), "empty": jnp.ones((5, 0)), "skip": None}
batch = (jnp.arange(12.0).reshape(4, 3), jnp.ones((4, 0)))
f = jax.jit(shard_map(body, mesh, in_specs=(P(), P("r")), out_specs=P("r")))
got, direct = f(fixed, batch), body(fixed, batch)
print(json.dumps({
    "devices": jax.local_device_count(),
    "shapes": [list(a.shape) for a in got],
    "equal": all(bool(np.array_equal(a, b)) for a, b in zip(got, direct)),
}))
"""


def test_zero_size_inputs_over_two_devices_give_the_unmapped_results():
    env = {k: v for k, v in os.environ.items() if k != "JAX_NUM_CPU_DEVICES"}
    env.update(
        JAXGEO_CPU_DEVICES="2",
        JAX_PLATFORMS="cpu",
        PYTHONPATH=os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]),
    )
    run = subprocess.run(
        [sys.executable, "-X", "faulthandler", "-c", SCRIPT],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out == {"devices": 2, "shapes": [[4, 3], [4]], "equal": True}


def test_one_device_and_a_bare_spec():
    """One spec for every argument (the lsq batch's form); an argument of zero-size arrays only."""
    P = jax.sharding.PartitionSpec
    mesh = jax.sharding.Mesh(np.array(jax.local_devices()[:1]), ("r",))

    def body(x, e):
        return x + e.shape[1], jnp.zeros((x.shape[0], e.shape[1]))

    x = jnp.arange(6.0).reshape(2, 3)
    got = jax.jit(shard_map(body, mesh, in_specs=P("r"), out_specs=P("r")))(x, jnp.ones((2, 0)))
    np.testing.assert_array_equal(got[0], x)
    assert got[1].shape == (2, 0)
