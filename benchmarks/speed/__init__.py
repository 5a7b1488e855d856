"""Speed studies: jaxgeo against its peers in the same run (``python -m benchmarks.speed.NAME``)."""
