"""The runtime floor: how jaxgeo's pure functions are compiled, kept and run, below every layer.

- :mod:`.jaxconfig` float64, the CPU devices per core, the persistent compilation cache
  (``JAXGEO_CACHE_DIR``), set before jax starts.
- :mod:`.kept` the decorators a pure function gets where it is defined (``@kept``,
  ``@kept_points``, :func:`~.kept.kept_solve`): its callers call it as a function, and how it
  compiles is decided here, not by them.
- :mod:`.exported` entry points kept on disk as serialized ``jax.export`` programs (a warm run
  neither traces nor compiles them), their XLA options, large programs compiled apart.
- :mod:`.executables` on a CPU, their compiled executables kept beside them (a warm run
  neither lowers nor compiles them).
- :mod:`.program_key` the key of a kept program (jaxgeo's source, versions, input structure).
- :mod:`.arrays` host data onto the device without compiling.
- :mod:`.shard` ``shard_map`` over the devices, zero-size inputs handled.
- :mod:`.interrupt` Ctrl-C / SIGTERM as a request the writers check.
- :mod:`.progress` the progress of long steps (count, rate, ETA) on stderr, silenced by ``--quiet``.

Nothing here imports another jaxgeo package (the import contract's bottom layer), and this
``__init__`` imports nothing: ``jaxgeo`` configures jax through :mod:`.jaxconfig` before jax is
imported.
"""
