"""Keyframe-based contour tracking (rotoscoping, docs/method.md §2) and its evaluation (§15.6).

* :mod:`nnsf.roto.curves`  — the Catmull-Rom curve model as constant linear maps, projection on polylines;
* :mod:`nnsf.roto.energy`  — the space-time energy, its Jacobian and the LM solver;
* :mod:`nnsf.roto.solve`   — :func:`track_clip` ("ours", "agarwala", "lk");
* :mod:`nnsf.roto.metrics` — point-to-curve error, PCK, simulated-user edit ratio;
* :mod:`nnsf.roto.figures` — the overlay figure (paper Fig. 5);
* :mod:`nnsf.roto.real`    — annotated real frames scored against their silhouettes
  (:mod:`nnsf.roto.lpc`: the same for LPC sprite sheets);
* :mod:`nnsf.roto.options` — the ``track:`` section of params.yaml as TrackOptions;
* :mod:`nnsf.roto.tracks`  — the TRACKS format (``curves.npz``), read and checked;
* :mod:`nnsf.roto.keypoints` — key points from the tracked curves (Eq. 2-3);
* :mod:`nnsf.roto.stage`   — the ``track`` stage (track every clip, then its key points);
* :mod:`nnsf.roto.evaluation` — the ``roto_eval`` stage (the trackers scored, §15.6).
"""
from nnsf.roto.solve import METHODS, TrackOptions, track_clip

__all__ = ["METHODS", "TrackOptions", "track_clip"]
