"""Two-level full-strip adjustment (003_a7d3ea260371d8c5.txt sections 6-9)."""
