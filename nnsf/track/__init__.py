"""Keyframe-based contour tracking (rotoscoping, docs/method.md §2) and its evaluation (§15.6).

* :mod:`nnsf.track.curves`  — the Catmull-Rom curve model as constant linear maps, projection on polylines;
* :mod:`nnsf.track.energy`  — the space-time energy, its Jacobian and the LM solver;
* :mod:`nnsf.track.solve`   — :func:`track_clip` ("ours", "agarwala", "lk");
* :mod:`nnsf.track.metrics` — point-to-curve error, PCK, simulated-user edit ratio;
* :mod:`nnsf.track.figures` — the overlay figure (paper Fig. 5);
* :mod:`nnsf.track.real`    — real frames (Kenney walk cycles) scored against silhouettes;
* :mod:`nnsf.track.options` — the ``track:`` section of params.yaml as TrackOptions;
* :mod:`nnsf.track.tracks`  — the TRACKS format (``curves.npz``), read and checked;
* :mod:`nnsf.track.keypoints` — key points from the tracked curves (Eq. 2-3);
* :mod:`nnsf.track.stage`   — the ``track`` stage (track every clip, then its key points);
* :mod:`nnsf.track.evaluation` — the ``tracking`` stage (the trackers scored, §15.6).
"""
from nnsf.track.solve import METHODS, TrackOptions, track_clip

__all__ = ["METHODS", "TrackOptions", "track_clip"]
