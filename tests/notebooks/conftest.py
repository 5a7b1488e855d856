"""Running the research notebooks (``notebooks/NN_*.ipynb``) top to bottom with nbclient, one
test file per notebook (``test_notebook_NN.py``), so that ``--dist loadfile`` can send them to
different xdist workers; ``tests/test_notebooks.py`` checks that each ``.ipynb`` is built from its
source.

The kernel runs in quick mode (``JAXGEO_NOTEBOOK_QUICK=1``): notebooks 01, 02 and 04 run every
cell, every check, on smaller workloads (fewer variants, GCP counts, layouts, gradient steps,
Monte-Carlo runs), as the ``QUICK`` line near the top of each says.
``JAXGEO_NOTEBOOK_QUICK=0 python -m pytest tests/notebooks`` runs them in full, as a user does.
Notebook 03 has no quick mode: its time is compilation, which a shorter strip does not shorten
(44 sub-scenes 111 s, 28 sub-scenes 118 s, run as a script on the same machine).

Almost all of a notebook's time is XLA compilation (one compiled solve per problem structure:
model, bias, number of GCPs), so quick mode leaves out variants, each of which is one more
compiled solve, rather than shrinking problems, which reuse the compiled programs anyway.
"""

import json
import os
import pathlib
import sys
import time

import pytest

REPO = pathlib.Path(__file__).resolve().parents[2]
NOTEBOOKS = REPO / "notebooks"


@pytest.fixture(scope="session")
def kernel_specs(tmp_path_factory):
    """A kernelspec that runs this interpreter with the repository importable, so the notebooks
    use the jaxgeo under test; matplotlib without a display; quick mode unless the environment
    says ``JAXGEO_NOTEBOOK_QUICK=0``."""
    pytest.importorskip("ipykernel")
    pytest.importorskip("matplotlib")
    from jupyter_client.kernelspec import KernelSpecManager

    root = tmp_path_factory.mktemp("kernels")
    spec = root / "kernels" / "jaxgeo-test"
    spec.mkdir(parents=True)
    env = {
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
        "MPLBACKEND": "Agg",
        "JAXGEO_NOTEBOOK_QUICK": os.environ.get("JAXGEO_NOTEBOOK_QUICK", "1"),
    }
    (spec / "kernel.json").write_text(
        json.dumps(
            {
                "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
                "display_name": "jaxgeo test",
                "language": "python",
                "env": env,
            }
        )
    )
    manager = KernelSpecManager()
    manager.kernel_dirs = [str(root / "kernels")]
    return manager


@pytest.fixture
def run_notebook(kernel_specs, tmp_path):
    """``run_notebook(name)`` executes ``notebooks/{name}.ipynb`` in a fresh kernel (an error in
    any cell fails the test), writes the executed copy to ``tmp_path`` for a look, checks that
    every code cell ran through to the last one's run-time line, and returns the printed text."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    from jupyter_client.manager import KernelManager

    def run(name: str) -> None:
        nb = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
        km = KernelManager(kernel_name="jaxgeo-test", kernel_spec_manager=kernel_specs)
        client = nbclient.NotebookClient(
            nb, km=km, timeout=600, resources={"metadata": {"path": str(tmp_path)}}
        )
        t = time.perf_counter()
        try:
            client.execute()
        finally:  # nbclient leaves a kernel it was handed running (each held 1-3 GB)
            if km.has_kernel:
                km.shutdown_kernel(now=True)
        print(f"{name}: {time.perf_counter() - t:.0f} s")
        nbformat.write(nb, tmp_path / f"{name}.ipynb")  # executed copy
        code = [c for c in nb.cells if c.cell_type == "code"]
        assert code and all(c.execution_count for c in code), f"{name}: a cell did not run"
        text = "".join(
            o.get("text", "") for c in code for o in c.outputs if o.output_type == "stream"
        )
        assert "notebook run time" in text, f"{name}: the last cell printed no run time"
        return text

    return run
