"""The deformation of a character's mesh, frame by frame (docs/method.md §10-§13, the paper's §5).

:class:`Deformer` is built once per character and handle set:

* **Key-point handles**: every key point of the rig (the 17, and an extra arm's three) is a
  barycentric combination of the corners of the triangle holding it, chosen among the triangles
  of the parts that key point ends a bone of (the shoulder pins the upper arm or the torso, never
  the underlay beneath the arm).
* **Subkeys** (``method="ours"``, the paper's): per limb, the vertices of the limb's own
  triangles nearest ``subkeys_per_limb`` samples of its rest Bézier curve (Eq. 9-11,
  :func:`nnsf.reshape.subkeys.init_subkeys`), tracked through the clip by Eq. 12-14
  (:class:`nnsf.reshape.subkeys.SubkeyTracker`); and the vertices about each elbow, which bend
  round it (:func:`elbow_fans`).  ``method="keypoints"`` leaves them out: the comparison baseline
  of the paper's Fig. 8.  A limb the body covers (a leg under a skirt) shows too little to hold its
  joints: every vertex of it is a subkey, in both methods.
* **Two-step ARAP** (:class:`nnsf.reshape.arap.TwoStepARAP`, Igarashi et al. 2005), factorised
  once; a frame is a few sparse products and one back-solve.  An underlay's own vertices then ride
  with the part beneath (:func:`underlay_riders`).

:meth:`Deformer.run` maps a clip of key points ``(T, 17, 2)`` to vertices ``(T, n, 2)``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from nnsf.reshape.arap import Handles, TwoStepARAP, barycentric
from nnsf.reshape.limbs import N_LIMBS, fit_omega
from nnsf.reshape.mesh import Mesh
from nnsf.reshape.subkeys import SubkeyTracker, Subkeys, init_subkeys
from nnsf.skeleton import N_JOINTS

#: Deformation methods: the paper's (key points and subkeys) and the key-points-only baseline.
METHODS = ("ours", "keypoints")
#: An underlay's own vertex rides with the affine map fitted to this many of its part's vertices
#: nearest it: more than a triangle's three, so no one strained triangle carries it.
RIDE_NEIGHBOURS = 8
#: An elbow's fan: its vertices within this many radii of the thicker arm bone and this share of
#: the shorter bone of the joint, weighted up to FAN_WEIGHT (docs/method.md §13, Elbows).
FAN_REACH, FAN_SHARE, FAN_WEIGHT = 1.25, 0.5, 3.0


def keypoint_handles(mesh: Mesh, rig, weight: float) -> Handles:
    """One handle per rig key point (module docstring)."""
    own = mesh.layer == 0
    rows, weights = [], []
    for k, p in enumerate(rig.keypoints):
        parts = np.unique(rig.bones[(rig.bones[:, 0] == k) | (rig.bones[:, 1] == k), 2])
        # A key point of hidden or covered parts only (a limb drawn as its twin, a knee under a skirt) pins nothing.
        weights.append(0.0 if len(parts) and set(parts.tolist()) <= set(rig.hidden) | set(rig.covered) else float(weight))
        parts = np.setdiff1d(parts, rig.covered)
        cand = np.flatnonzero(own & np.isin(mesh.parts, parts))
        bary, tri = barycentric(mesh.vertices, mesh.triangles[cand], p[None]) if len(cand) else (None, None)
        # A key point just outside its parts' triangles (under a limb drawn over its part, in a
        # seam) still pins its own part, by the nearest triangle's affine extension: pinning the
        # limb over it would tie the limb to the body.  Only far from its parts (more than about a
        # triangle), the triangle it lies in.
        if bary is None or bary.min() < -1.0:
            cand = np.flatnonzero(own)
            bary, tri = barycentric(mesh.vertices, mesh.triangles[cand], p[None])
        rows.append((mesh.triangles[cand[tri[0]]], bary[0]))
    m = sp.csr_matrix((np.concatenate([b for _, b in rows]),
                       (np.repeat(np.arange(len(rows)), 3), np.concatenate([t for t, _ in rows]))),
                      shape=(len(rows), mesh.n_vertices))
    return Handles(m, np.asarray(weights))


def elbow_fans(mesh: Mesh, rig) -> list:
    """Per elbow (a forearm hanging from an upper arm; hidden arms have none): ``(shoulder, elbow,
    wrist, vertices (k,), weights (k,))``: the vertices only the two segments' drawn triangles use,
    within :data:`FAN_REACH` radii and :data:`FAN_SHARE` of the shorter bone of the elbow, weighted
    ``FAN_WEIGHT (1 − (d / reach)²)`` so the fan fades into what ARAP makes of the arm."""
    own = mesh.layer == 0
    count = np.zeros((mesh.n_vertices, len(rig.parts)), np.int64)
    np.add.at(count, (mesh.triangles[own].ravel(), np.repeat(mesh.parts[own], 3)), 1)
    fans, kp = [], rig.keypoints
    for c, (p, j) in enumerate(zip(rig.parent, rig.joint)):
        if p <= 0 or "forearm" not in rig.parts[c] or {p, c} & set(rig.hidden + rig.covered):
            continue
        a = rig.bones[(rig.bones[:, 2] == p) & (rig.bones[:, 1] == j), 0][0]
        b = rig.bones[(rig.bones[:, 2] == c) & (rig.bones[:, 0] == j), 1][0]
        reach = min(FAN_REACH * rig.radius[np.isin(rig.bones[:, 2], (p, c))].max(),
                    FAN_SHARE * min(np.linalg.norm(kp[a] - kp[j]), np.linalg.norm(kp[b] - kp[j])))
        d = np.linalg.norm(mesh.vertices - kp[j], axis=1)
        mine = count[:, [p, c]].sum(axis=1)
        v = np.flatnonzero((mine > 0) & (mine == count.sum(axis=1)) & (d < reach))
        fans.append((a, j, b, v, FAN_WEIGHT * (1 - (d[v] / reach) ** 2)))
    return fans


def fan_targets(fans, rest_kp: np.ndarray, rest_vertices: np.ndarray, kp: np.ndarray) -> np.ndarray:
    """Targets ``(T, k, 2)`` of the fans' vertices for key points ``(T, K, 2)``.  A vertex keeps its
    distance to the elbow.  Its angle about it, from the upper arm, is stretched with the angle
    between the bones on the side that opens, so the outside of the bend is an arc; on the side
    that closes it turns with the nearer bone, as two capsules overlap."""
    ang = lambda d: np.arctan2(d[..., 1], d[..., 0])
    full, out = 2 * np.pi, []
    for a, j, b, v, _ in fans:
        a0 = ang(rest_kp[a] - rest_kp[j])
        beta0 = (ang(rest_kp[b] - rest_kp[j]) - a0) % full
        d = rest_vertices[v] - rest_kp[j]
        psi, rad = (ang(d) - a0) % full, np.hypot(d[:, 0], d[:, 1])
        up = ang(kp[:, a] - kp[:, j])[:, None]
        turn = (ang(kp[:, b] - kp[:, j])[:, None] - up - beta0 + np.pi) % full - np.pi
        beta = np.clip(beta0 + turn, 0.1, full - 0.1)                   # (T, 1): the bend, never folded through
        first = psi < beta0                                             # between the upper arm and the forearm
        stretched = np.where(first, psi * beta / beta0, beta + (psi - beta0) * (full - beta) / (full - beta0))
        child = np.where(first, psi >= beta0 / 2, psi < (beta0 + full) / 2)
        psi = np.where(first == (beta > beta0), stretched, np.where(child, psi + beta - beta0, psi))
        out.append(kp[:, j, None] + rad[:, None] * np.stack([np.cos(up + psi), np.sin(up + psi)], axis=-1))
    return np.concatenate(out, axis=1) if out else np.zeros((len(kp), 0, 2))


def part_owner(mesh: Mesh, own=None) -> np.ndarray:
    """The part ``(n,)`` whose drawn (layer 0) triangles, or ``own`` ``(t,)`` bool, alone use each vertex,
    −1 on none or on two parts' (a seam's vertex moves with both)."""
    own = mesh.layer == 0 if own is None else own
    count = np.zeros((mesh.n_vertices, int(mesh.parts.max()) + 1), dtype=np.int64)
    np.add.at(count, (mesh.triangles[own].ravel(), np.repeat(mesh.parts[own], 3)), 1)
    return np.where((count > 0).sum(axis=1) == 1, count.argmax(axis=1), -1)


def underlay_riders(mesh: Mesh, rig=None):
    """The underlay's own vertices ``(k,)`` (used by no triangle of the drawing; not a covered limb's,
    ``rig``'s, which its subkeys carry) and a sparse ``(k, n)`` map placing each from its part's own vertices nearest it.

    An underlay is joined to its part along the cut beside it, which may be short; solved by ARAP
    with the rest, a patch could swing about that seam and show beside its part (over a leg the body
    hides).  Instead each of its own vertices rides with the part beneath: the least-squares affine
    map (rest → deformed) of the :data:`RIDE_NEIGHBOURS` vertices nearest it that the part alone
    uses; one triangle's map would magnify its strain by the rider's distance over its size (a
    sliver along a seam, one corner on the limb above, carried the patch off as a long wedge).
    """
    owner, under = part_owner(mesh), (mesh.layer == 1) & ~np.isin(mesh.parts, getattr(rig, "covered", ()))
    riders = np.setdiff1d(mesh.triangles[under], mesh.triangles[~under])
    part = np.zeros(mesh.n_vertices, np.int64)
    part[mesh.triangles[under]] = mesh.parts[under, None]
    near = np.zeros((len(riders), RIDE_NEIGHBOURS), np.int64)
    for p in np.unique(part[riders]):
        anchors = np.flatnonzero(owner == p)
        if len(anchors) < 3:
            anchors = np.unique(mesh.triangles[~under & (mesh.parts == p)])
        k = cKDTree(mesh.vertices[anchors]).query(mesh.vertices[riders[part[riders] == p]], RIDE_NEIGHBOURS)[1]
        near[part[riders] == p] = anchors[np.minimum(k, len(anchors) - 1)]
    # Weights w (summing to 1) with w @ [x y 1] of the neighbours = the rider's [x y 1] at rest.
    hom = lambda x: np.concatenate([x, np.ones(x.shape[:-1] + (1,))], axis=-1)
    w = np.einsum("ri,rik->rk", hom(mesh.vertices[riders]), np.linalg.pinv(hom(mesh.vertices[near])))
    return riders, sp.csr_matrix((w.ravel(), (np.repeat(np.arange(len(riders)), RIDE_NEIGHBOURS), near.ravel())),
                                 shape=(len(riders), mesh.n_vertices))


class Deformer:
    """Handles, subkeys and the prefactorised two-step ARAP of one mesh (module docstring).

    Parameters
    ----------
    mesh : :class:`~nnsf.reshape.mesh.Mesh`; rig : :class:`~nnsf.reshape.rig.Rig`.
    mask : ``(H, W)`` bool, the drawing's silhouette (the rest ω is fitted to it, Eq. 10).
    method : ``"ours"`` (key points, subkeys and elbow fans) or ``"keypoints"``.
    subkeys_per_limb : subkeys per limb (Eq. 11).
    weight : handle weight w of every handle (the shape terms weigh 1 per triangle corner; with 10
        the handles are met within about a pixel in strained poses and the normal matrices stay
        well conditioned).
    propagation : subkey propagation, ``"limb-frame"`` or ``"eq12"``
        (:class:`~nnsf.reshape.subkeys.SubkeyTracker`).
    """

    def __init__(self, mesh: Mesh, rig, mask: np.ndarray, method: str = "ours", subkeys_per_limb: int = 4,
                 weight: float = 10.0, propagation: str = "limb-frame"):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        self.mesh, self.rig, self.method = mesh, rig, method
        kp = rig.keypoints[:N_JOINTS]
        self.rest_omega = fit_omega(mask, kp)
        handles = keypoint_handles(mesh, rig, weight)
        self.tracker, self.fans = None, []
        self.subkeys = Subkeys(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2)))
        ours = method == "ours" and subkeys_per_limb > 0
        if ours or rig.covered:
            # A limb's subkeys are vertices of its own triangles that no other part shares; a covered
            # limb's are all its vertices, its underlay's too, in either method: no joint of it is drawn.
            owner, every = part_owner(mesh), part_owner(mesh, np.ones(len(mesh.layer), bool)) if rig.covered else None
            candidates = [np.flatnonzero((every if 2 + i in rig.covered else owner) == 2 + i) for i in range(N_LIMBS)]
            self.subkeys = init_subkeys(mesh.vertices, kp, self.rest_omega, per_limb=subkeys_per_limb * ours,
                                        candidates=candidates, whole=[p - 2 for p in rig.covered])
            handles = handles + Handles.at_vertices(mesh.n_vertices, self.subkeys.vertex, weight)
            self.tracker = SubkeyTracker(self.subkeys, kp, self.rest_omega, propagation=propagation)
            self.fans = elbow_fans(mesh, rig) if ours else []
            for *_, v, w in self.fans:
                handles = handles + Handles.at_vertices(mesh.n_vertices, v, w)
        self.handles = handles
        self.arap = TwoStepARAP(mesh.vertices, mesh.triangles, handles)
        self.riders, self.ride = underlay_riders(mesh, rig)

    def targets(self, keypoints: np.ndarray, omega=None) -> np.ndarray:
        """Handle targets ``(T, m, 2)`` for key points ``(T, 17, 2)``; subkeys tracked from rest."""
        kp = np.asarray(keypoints, dtype=np.float64)
        g = self.rig.full_keypoints(kp)
        if self.tracker is None:
            return g
        return np.concatenate([g, self.tracker.track(kp, omega),
                               fan_targets(self.fans, self.rig.keypoints, self.mesh.vertices, g)], axis=1)

    def run(self, keypoints: np.ndarray, omega=None) -> np.ndarray:
        """Deformed vertices ``(T, n, 2)`` for key points ``(T, 17, 2)`` (pixels); ``omega``
        ``(T, 8, 2)`` or ``(8, 2)`` keyframed limb curves (default: the rest ω every frame)."""
        kp = np.asarray(keypoints, dtype=np.float64)
        if kp.ndim != 3 or kp.shape[1:] != (N_JOINTS, 2):
            raise ValueError(f"expected key points (frames, {N_JOINTS}, 2), got {kp.shape}")
        if len(kp) == 0:
            return np.zeros((0, self.mesh.n_vertices, 2))
        V = self.arap.deform(self.targets(kp, omega))
        V[:, self.riders] = np.stack([self.ride @ v for v in V])
        return V
