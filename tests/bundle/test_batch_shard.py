"""Batches of independent adjustments sharded over devices and hosts (in subprocesses: the
device count must be set before jax starts). Results must equal the unsharded run."""

import json
import os
import pathlib
import socket
import subprocess
import sys

WORKER = pathlib.Path(__file__).with_name("batch_worker.py")
REPO = pathlib.Path(__file__).resolve().parents[2]


def _env():
    # the host's CPU devices, on a GPU machine too (two processes on one GPU: NCCL refuses)
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    return env


def _last_json(out: str) -> dict:
    return json.loads(out.strip().splitlines()[-1])


def test_batch_shard_over_4_host_devices_equals_unsharded():
    run = subprocess.run(
        [sys.executable, str(WORKER), "shard"],
        capture_output=True, text=True, env=_env(), timeout=900,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    out = _last_json(run.stdout)
    assert out["devices"] == 4
    assert out["successful"] == 8 and out["results_equal"]
    # the sharded program is compiled for another batch size: XLA may vectorise the per-block
    # segment sums differently (rounding at 1e-16), and the solves stop within tol of each other
    assert out["theta"] <= 1e-9


def test_batch_distributed_two_processes_equals_one():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    procs = [
        subprocess.Popen(
            [sys.executable, str(WORKER), "distributed", str(i), str(port)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=_env(),
        )  # fmt: skip
        for i in range(2)
    ]
    outs = [p.communicate(timeout=900) for p in procs]
    for p, (_, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err[-3000:]
    for stdout, _ in outs:
        out = _last_json(stdout)
        assert out["processes"] == 2
        assert out["successful"] == 8 and out["results_equal"]
        # each process runs its 4 problems on 4 lanes, one process its 8 on 8: as with the
        # devices above, another vectorisation (rounding at 1e-16), solves within tol
        assert out["theta"] <= 1e-9
