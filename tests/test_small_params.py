"""The small pipeline the slow tests reproduce names every parameter the real one does.

``dvc repro`` refuses a stage whose declared ``params`` are missing from ``params.yaml``;
this fast check fails first, with the missing keys, when a new parameter is added to
``params.yaml`` but not to ``test_pipeline.SMALL_PARAMS``.
"""
from pathlib import Path

import yaml

from test_pipeline import SMALL_PARAMS

ROOT = Path(__file__).resolve().parents[1]


def leaf_keys(tree, prefix=""):
    """Dotted names of every leaf of a nested mapping (lists count as leaves)."""
    keys = set()
    for name, value in tree.items():
        dotted = f"{prefix}{name}"
        if isinstance(value, dict) and value:
            keys |= leaf_keys(value, dotted + ".")
        else:
            keys.add(dotted)
    return keys


def staged_sections():
    """Top-level params.yaml sections some dvc.yaml stage declares (hand-run ones are not)."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    return {str(name).split(".")[0] for stage in stages.values() for name in stage.get("params", [])}


def test_small_params_have_every_key_of_params_yaml():
    sections = staged_sections()
    assert {"roto", "nnsf", "reshape", "animate"} <= sections
    real = {key for key in leaf_keys(yaml.safe_load((ROOT / "params.yaml").read_text()))
            if key.split(".")[0] in sections}
    small = leaf_keys(yaml.safe_load(SMALL_PARAMS))
    assert sorted(real - small) == []
    # mlflow is read by every stage at start-up, not declared as a dvc param
    assert sorted(small - real - {"mlflow.experiment"}) == []
