"""The peers the studies compare jaxgeo with, as importable helpers (no study of their own):
``rpc`` (shareloc, rpcm loaders), ``strip`` (the strip problem in numpy, scipy), ``strip_ceres``
(Ceres through pyceres), ``strip_synth`` (a synthetic strip problem for them)."""
