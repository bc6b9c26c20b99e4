"""The ``track:`` section of params.yaml as :class:`~nnsf.roto.solve.TrackOptions` keyword arguments.

The tracker's defaults are :class:`~nnsf.roto.solve.TrackOptions`' (its
energy weights :class:`~nnsf.roto.energy.Weights`'); this module only maps
params.yaml keys onto them and checks each value against the params schema.
"""
from __future__ import annotations

from nnsf.params import checked, require

#: params.yaml ``track.<key>`` -> (TrackOptions field, kind, lower bound)
OPTION_PARAMS: dict[str, tuple[str, str, float]] = {
    "w_velocity": ("velocity", "num", 0.0),
    "w_length": ("length", "num", 0.0),
    "w_length_anchor": ("length_anchor", "num", 0.0),
    "w_curvature": ("curvature", "num", 0.0),
    "w_edge": ("edge", "num", 0.0),
    "w_sketch": ("sketch", "num", 0.0),
    "w_colour": ("colour", "num", 0.0),
    "window": ("K", "int", 1),
    "samples": ("n_samples", "int", 3),
    "levels": ("levels", "int", 1),
    "max_iter": ("max_nfev", "int", 1),
}
#: the same for keys that may be absent (then 0: the term is off, as before they existed)
OPTIONAL_PARAMS: dict[str, tuple[str, str, float]] = {
    "w_slide": ("slide", "num", 0.0),
    "edge_gate": ("edge_gate", "num", 0.0),
    "velocity_trust": ("velocity_trust", "bool", 0.0),
    "snap": ("snap", "num", 0.0),
}


def track_options(params: dict) -> dict:
    """TrackOptions keyword arguments from the ``track`` section (InputError naming the field).

    Each value is checked by :func:`nnsf.params.require` against the params
    schema, the ranges ``nnsf check`` applies.
    """
    out = {name: require(params, f"roto.{key}") for key, (name, _, _) in OPTION_PARAMS.items()}
    out["init"] = require(params, "roto.init")
    out["lk_end"] = require(params, "roto.lk_end")
    for key, (name, kind, _) in OPTIONAL_PARAMS.items():     # absent in older params files: off
        out[name] = checked(params, f"roto.{key}", False if kind == "bool" else 0.0)
    out["snap_to"] = checked(params, "roto.snap_to", "profile")
    return out


def method(params: dict) -> str:
    """``roto.method``: one of :data:`nnsf.params.TRACKERS` (the params schema checks it)."""
    return require(params, "roto.method")
