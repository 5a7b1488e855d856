"""The research notebooks run top to bottom (nbclient, a kernel on this interpreter), so they
cannot rot; and each ``notebooks/NN_*.ipynb`` is what ``notebooks/make_notebooks.py`` builds from
its source in ``notebooks/src/``."""

import os
import pathlib
import sys
import time

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
NOTEBOOKS = REPO / "notebooks"
NAMES = sorted(p.stem for p in (NOTEBOOKS / "src").glob("[0-9][0-9]_*.py"))

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
pytest.importorskip("matplotlib")


def test_four_notebooks():
    assert NAMES == [
        "01_cartosat1_sensor_models",
        "02_kepler_rotation_orders",
        "03_full_strip",
        "04_differentiable",
    ]


@pytest.mark.parametrize("name", NAMES)
def test_notebook_is_built_from_its_source(name):
    sys.path.insert(0, str(NOTEBOOKS))
    try:
        import make_notebooks
    finally:
        sys.path.remove(str(NOTEBOOKS))
    ipynb = (NOTEBOOKS / f"{name}.ipynb").read_text()
    assert ipynb == make_notebooks.render(NOTEBOOKS / "src" / f"{name}.py"), (
        f"notebooks/{name}.ipynb is out of date: run python notebooks/make_notebooks.py"
    )


@pytest.fixture(scope="module")
def kernel_env(tmp_path_factory):
    """A kernelspec that runs this interpreter with the repository importable, so the notebooks
    use the jaxgeo under test; matplotlib without a display."""
    from jupyter_client.kernelspec import KernelSpecManager

    root = tmp_path_factory.mktemp("kernels")
    spec = root / "kernels" / "jaxgeo-test"
    spec.mkdir(parents=True)
    env = {
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
        "MPLBACKEND": "Agg",
    }
    (spec / "kernel.json").write_text(
        __import__("json").dumps(
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


@pytest.mark.parametrize("name", NAMES)
def test_notebook_runs(name, kernel_env, tmp_path):
    from jupyter_client.manager import KernelManager

    nb = nbformat.read(NOTEBOOKS / f"{name}.ipynb", as_version=4)
    km = KernelManager(kernel_name="jaxgeo-test", kernel_spec_manager=kernel_env)
    client = nbclient.NotebookClient(
        nb,
        km=km,
        timeout=600,
        resources={"metadata": {"path": str(tmp_path)}},
    )
    t = time.perf_counter()
    try:
        client.execute()
    finally:  # nbclient leaves a kernel it was handed running (each held 1-3 GB)
        if km.has_kernel:
            km.shutdown_kernel(now=True)
    print(f"{name}: {time.perf_counter() - t:.0f} s")
    out = tmp_path / f"{name}.ipynb"
    nbformat.write(nb, out)  # executed copy, for a look when a number changes
