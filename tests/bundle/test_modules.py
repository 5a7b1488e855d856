"""The layout: every module of ``jaxgeo.bundle`` imports as a module, under its own name."""

import importlib
import pkgutil
import types

import jaxgeo
import jaxgeo.bundle

MODULES = (
    "adjustment",
    "band",
    "build",
    "build.checks",
    "build.grouping",
    "build.points",
    "build.priors",
    "config",
    "covariance",
    "diagnose",
    "batch",
    "errors",
    "export",
    "factor",
    "ground",
    "lanes",
    "lm",
    "loss",
    "observations",
    "problem",
    "report",
    "result",
    "schur",
    "snooping",
    "solve",
    "trust_region",
)


def test_every_module_imports_as_a_module():
    found = {
        m.name.removeprefix("jaxgeo.bundle.")
        for m in pkgutil.walk_packages(jaxgeo.bundle.__path__, "jaxgeo.bundle.")
    }
    assert found == set(MODULES)
    for name in MODULES:
        module = importlib.import_module(f"jaxgeo.bundle.{name}")
        assert isinstance(module, types.ModuleType) and module.__name__ == f"jaxgeo.bundle.{name}"
        # ``import jaxgeo.bundle.x as m`` gives the module: no function shadows it
        parent, _, leaf = f"jaxgeo.bundle.{name}".rpartition(".")
        assert getattr(importlib.import_module(parent), leaf) is module


def test_adjust_is_the_one_call_entry_point():
    from jaxgeo.bundle.adjustment import adjust

    assert jaxgeo.adjust is adjust and jaxgeo.bundle.adjust is adjust
