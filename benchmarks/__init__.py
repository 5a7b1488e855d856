"""jaxgeo's benchmarks, run from the repository root as modules (no ``sys.path`` edits):

    python -m benchmarks.speed.projection --help
    python -m benchmarks.report                # benchmarks/README.md and README.md's table

``speed/`` times jaxgeo against its peers, ``accuracy/`` measures what it computes against a
reference; ``peers/`` holds the peers (loaders, solvers, their synthetic problem), ``harness``
the timing and machine description every study shares, ``data`` where the input data lives,
``results/`` one JSON per run (``<study>-<case>-<machine>.json``), ``report`` the generator of
the READMEs from those JSON files.
"""
