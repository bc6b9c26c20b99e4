"""The registry of the pipeline's stages: stage name -> the function that runs it.

Each sub-package owns its stages in its ``stage.py`` (docs/architecture.md);
this module only says where each one is, and loads it on first use, so that
a stage imports the code it runs and nothing else (the ``deps`` of each
``dvc.yaml`` stage are exactly those files; tests/test_pipeline.py checks
them).  Only :mod:`nnsf.cli`, ``flows/`` and the tests import this module;
nothing in a sub-package does (tests/test_architecture.py).

``stages.evaluate(params)`` and ``from nnsf.stages import features`` work as
if the functions were defined here.  Every stage takes the parsed
``params.yaml`` dict and explicit paths (defaults: :mod:`nnsf.pipeline`),
writes its outputs atomically and returns a :class:`nnsf.pipeline.StageResult`.
"""
from __future__ import annotations

import importlib
from typing import Callable

#: Stage name (as in dvc.yaml) -> "module:function".  ``sweep`` runs as its
#: points (``sweep_grid`` lists them, ``sweep_point`` scores one; flows/sweep.py).
REGISTRY: dict[str, str] = {
    "frames": "nnsf.frames.stage:render_frames",
    "roto": "nnsf.roto.stage:roto",
    "roto_eval": "nnsf.roto.evaluation:roto_eval",
    "data": "nnsf.datasets.stage:data",
    "features": "nnsf.datasets.stage:features",
    "factorize": "nnsf.factor.stage:factorize",
    "evaluate": "nnsf.evaluate.stage:evaluate",
    "isomap": "nnsf.evaluate.stage:isomap",
    "sweep_grid": "nnsf.evaluate.stage:sweep_grid",
    "sweep_point": "nnsf.evaluate.stage:sweep_point",
    "heldout": "nnsf.evaluate.heldout_report:heldout",
    "translate": "nnsf.factor.stage:translate",
    "reshape": "nnsf.reshape.stage:reshape",
    "styles": "nnsf.factor.stage:styles",
    "animate": "nnsf.animate.stage:animate",
    "results": "nnsf.results:results",
}


def get(name: str) -> Callable:
    """The function registered as ``name`` (imported now)."""
    try:
        target = REGISTRY[name]
    except KeyError:
        raise AttributeError(f"module 'nnsf.stages' has no stage {name!r}") from None
    module, function = target.split(":")
    return getattr(importlib.import_module(module), function)


def __getattr__(name: str) -> Callable:
    return get(name)
