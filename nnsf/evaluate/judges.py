"""Independent judges of translated clips: style and content classifiers trained on real clips only.

The held-out evaluation (:mod:`nnsf.evaluate.translation`) asks of every
synthesised clip "is it of the target style?" and "is it of the cell's
content?".  The judges here answer, and they are kept apart from the
translation code on purpose: they share no feature, normalisation or
classifier with it.  This module imports nothing of ``nnsf`` (only numpy and
scikit-learn): it reads a clip as key points ``(n, 17, 2)`` in whatever 2D
coordinates the caller has -- the held-out evaluation passes the real clips
as read from the table (pixels) and every method's output mapped to the
target style's character in pixels, i.e. what a caller of the translation
gets -- and normalises them itself:

* position: every key point is taken relative to the root (the pelvis) in
  each frame;
* size: the root-relative pose is divided by the clip's own body length,
  the median over its frames of the summed lengths of its 16 bones (so a
  clip's scale, whatever unit it comes in, does not enter; nothing about
  other clips or any fitted template is used);
* the statistics are then standardised by a scaler fitted on the judges'
  training clips only (part of each fitted pipeline).

The key-point order is the data contract's (Human3.6M, docs/formats.md):
:data:`PARENTS` spells out which key point hangs from which; a test checks
that it is the contract's tree.

Each judge is *unconditioned*: the style classifier is not told the content
and the content classifier is not told the style.  Every judge is fitted on
the real clips it is given (the caller passes only the clips outside the
hidden cell).

Families (:data:`FAMILIES`):

* ``"lr"`` -- :func:`pose_statistics` (per key point: mean, standard deviation
  and mean |velocity| of the root-relative, size-normalised pose),
  standardised, multinomial logistic regression;
* ``"nn1"`` -- the same statistics, standardised, one nearest neighbour;
* ``"angles"`` -- :func:`angle_statistics` (per bone: circular mean, spread
  and mean |angular velocity| of its direction in the image), standardised,
  an RBF support-vector machine: a different representation (bone
  directions are blind to size and to posture offsets that shift key
  points) and a different classifier family.

``"all"`` (in :meth:`Judges.score`) counts a clip as recognised only when
every family recognises it.
"""
from __future__ import annotations

import numpy as np
from sklearn.linear_model import LogisticRegression
from sklearn.neighbors import KNeighborsClassifier
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

__all__ = ["FAMILIES", "PARENTS", "body_length", "pose_statistics", "angle_statistics", "Judges"]

#: Parent of each of the 17 key points in the data contract's order (pelvis, r_hip, r_knee,
#: r_ankle, l_hip, l_knee, l_ankle, spine, thorax, neck, head_top, l_shoulder, l_elbow, l_wrist,
#: r_shoulder, r_elbow, r_wrist); the pelvis is the root (-1).  Written out here rather than
#: imported, so that this module depends on nothing of the project but the clips' format.
PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 9, 8, 11, 12, 8, 14, 15)

#: Judge families, in table order.
FAMILIES: tuple[str, ...] = ("lr", "nn1", "angles")

_ROOT = PARENTS.index(-1)
_CHILDREN = np.array([j for j, p in enumerate(PARENTS) if p >= 0])
_PARENT_OF = np.array([PARENTS[j] for j in _CHILDREN])


def _check_clip(P) -> np.ndarray:
    P = np.asarray(P, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (len(PARENTS), 2) or len(P) < 1:
        raise ValueError(f"judges: a clip is (n >= 1, {len(PARENTS)}, 2) key points, got shape {P.shape}")
    if not np.isfinite(P).all():
        raise ValueError("judges: a clip has non-finite key points")
    return P


def body_length(P) -> float:
    """The clip's own size: median over frames of the summed lengths of its 16 bones (P's unit).

    A sum over all bones, not one bone, so that a bone foreshortened by the
    pose (a bowing torso, a leg swung towards the camera) moves it little.
    """
    P = _check_clip(P)
    B = P[:, _CHILDREN] - P[:, _PARENT_OF]
    size = float(np.median(np.linalg.norm(B, axis=-1).sum(axis=1)))
    if not size > 0:
        raise ValueError("judges: a clip has zero size (every bone of zero length)")
    return size


def pose_statistics(P) -> np.ndarray:
    """Clip statistics of the root-relative, size-normalised pose, ``(96,)``.

    ``P`` is ``(n, 17, 2)`` key points (any one unit).  Every key point but
    the root is taken relative to the root (the pelvis) in each frame and
    divided by the clip's :func:`body_length`; per coordinate: the mean over
    frames, the standard deviation, and the mean absolute frame-to-frame
    change (per frame).  A one-frame clip has zero spread and motion.
    """
    P = _check_clip(P)
    R = (P - P[:, _ROOT:_ROOT + 1])[:, _CHILDREN].reshape(len(P), -1) / body_length(P)     # (n, 32)
    V = np.abs(np.diff(R, axis=0)).mean(axis=0) if len(R) > 1 else np.zeros(R.shape[1])
    return np.concatenate([R.mean(axis=0), R.std(axis=0), V])


def angle_statistics(P) -> np.ndarray:
    """Clip statistics of the bone directions, ``(64,)``.

    Per bone (parent -> child), its direction angle θ_t in the image: the
    circular mean as (mean cos θ, mean sin θ) -- 2 numbers whose length also
    says how steady the direction is --, the circular spread sqrt(−2 ln R̄)
    with R̄ that length, and the mean absolute angular change per frame
    (wrapped to (−π, π]), radians.
    """
    P = _check_clip(P)
    B = P[:, _CHILDREN] - P[:, _PARENT_OF]                                # (n, 16, 2)
    theta = np.arctan2(B[..., 1], B[..., 0])
    c, s = np.cos(theta).mean(axis=0), np.sin(theta).mean(axis=0)
    r = np.clip(np.hypot(c, s), 1e-12, 1.0)
    spread = np.sqrt(-2.0 * np.log(r))
    if len(P) > 1:
        d = np.angle(np.exp(1j * np.diff(theta, axis=0)))
        speed = np.abs(d).mean(axis=0)
    else:
        speed = np.zeros(theta.shape[1])
    return np.concatenate([c, s, spread, speed])


def _model(family: str, seed: int):
    if family == "lr":
        return make_pipeline(StandardScaler(), LogisticRegression(C=1.0, max_iter=2000))
    if family == "nn1":
        return make_pipeline(StandardScaler(), KNeighborsClassifier(n_neighbors=1))
    if family == "angles":
        return make_pipeline(StandardScaler(), SVC(kernel="rbf", C=10.0, gamma="scale", random_state=seed))
    raise ValueError(f"unknown judge family {family!r}; choose from {FAMILIES}")


_FEATURES = {"lr": pose_statistics, "nn1": pose_statistics, "angles": angle_statistics}


class Judges:
    """Style and content classifiers of every family, fitted on real clips.

    Parameters
    ----------
    families : names from :data:`FAMILIES`.
    seed : random state of the families that have one.

    Attributes (after ``fit``)
    --------------------------
    style_models_, content_models_ : dict family -> fitted sklearn pipeline.
    n_train_ : number of training clips.
    """

    def __init__(self, families=FAMILIES, seed: int = 0):
        self.families = tuple(families)
        self.seed = seed

    def _vectors(self, clips, family):
        f = _FEATURES[family]
        return np.stack([f(P) for P in clips])

    def fit(self, clips, style, content):
        """Fit on real clips: ``clips`` a list of ``(n_i, 17, 2)``, ``style``/``content`` one label each."""
        bad = [f for f in self.families if f not in FAMILIES]
        if bad or not self.families:
            raise ValueError(f"judges: families must be a non-empty subset of {FAMILIES}, got {self.families}")
        clips = list(clips)
        style = np.asarray(style).astype(str)
        content = np.asarray(content).astype(str)
        if not (len(clips) == len(style) == len(content)) or len(clips) < 2:
            raise ValueError(f"judges: need one style and one content per clip and >= 2 clips, got "
                             f"{len(clips)} clips, {len(style)} styles, {len(content)} contents")
        if len(set(style)) < 2 or len(set(content)) < 2:
            raise ValueError("judges: need at least two styles and two contents to tell apart")
        self.style_models_, self.content_models_ = {}, {}
        for fam in self.families:
            F = self._vectors(clips, fam)
            self.style_models_[fam] = _model(fam, self.seed).fit(F, style)
            self.content_models_[fam] = _model(fam, self.seed).fit(F, content)
        self.n_train_ = len(clips)
        return self

    def predict(self, clips) -> dict:
        """``{family: (style labels (m,), content labels (m,))}`` for a list of clips."""
        if not hasattr(self, "style_models_"):
            raise ValueError("judges: call fit first")
        clips = list(clips)
        out = {}
        for fam in self.families:
            F = self._vectors(clips, fam)
            out[fam] = (self.style_models_[fam].predict(F), self.content_models_[fam].predict(F))
        return out

    def score(self, clips, style, content) -> dict:
        """Per family and for ``"all"``: 0/1 arrays ``style_ok (m,)``, ``content_ok (m,)``.

        ``style``/``content`` are the labels the clips should have (one, or one per clip).
        ``"all"`` is 1 where every family is right.
        """
        clips = list(clips)
        style = np.broadcast_to(np.asarray(style).astype(str), (len(clips),))
        content = np.broadcast_to(np.asarray(content).astype(str), (len(clips),))
        pred = self.predict(clips)
        out = {fam: ((ps == style).astype(int), (pc == content).astype(int)) for fam, (ps, pc) in pred.items()}
        out["all"] = (np.min([v[0] for v in out.values()], axis=0),
                      np.min([v[1] for v in out.values()], axis=0))
        return out
