"""Accuracy studies: jaxgeo's results against a reference (truth, s2p, CARS), run as
``python -m benchmarks.accuracy.NAME``."""
