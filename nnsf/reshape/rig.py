"""A character ready to be driven: mesh, limb curves, subkeys and a factorised ARAP.

:class:`Rig` ties the pieces of this package together.  Frames are given as
key points ``(T, 17, 2)`` in the character's pixels (e.g. synthesized
features mapped back with :meth:`nnsf.skeleton.Unifier.inverse_transform`)
and, optionally, keyframe-interpolated ω ``(T, 8, 2)``; the result is the
deformed vertices ``(T, n, 2)``.  A renderer needs, besides those,
``rig.mesh.triangles``, ``rig.mesh.parts`` and the texture coordinates
``rig.mesh.vertices`` (the rest positions, in texture pixels).

Handle sets: ``"subkeys"`` (the paper's method: the 17 key points as
barycentric handles plus the subkey vertices) or ``"keypoints"`` (the
comparison baseline of the paper's Fig. 8: the key points alone).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nnsf.reshape.arap import Handles, TwoStepARAP
from nnsf.reshape.character import Character
from nnsf.reshape.limbs import N_LIMBS, STRAIGHT, fit_omega
from nnsf.reshape.layers import build_mesh
from nnsf.reshape.mesh import Mesh
from nnsf.reshape.subkeys import SubkeyTracker, Subkeys, init_subkeys
from nnsf.skeleton import N_JOINTS
from nnsf.reshape.drive import TORSO
from nnsf.reshape.pieces import TabMotion
from nnsf.skeleton import JOINT_INDEX as J

HANDLE_SETS = ("subkeys", "keypoints")

#: The chains :meth:`Rig.drive` moves with a moved pivot: (pivot, points below it, the next first).
DRIVE_CHAINS = ((J["l_shoulder"], (J["l_elbow"], J["l_wrist"])), (J["r_shoulder"], (J["r_elbow"], J["r_wrist"])),
                (J["l_hip"], (J["l_knee"], J["l_ankle"])), (J["r_hip"], (J["r_knee"], J["r_ankle"])),
                (J["neck"], (J["head_top"],)))


@dataclass
class Rig:
    """A meshed character with its handles and prefactorised deformer.

    Build with :meth:`build`.  Attributes: ``character``, ``mesh``,
    ``rest_omega`` ``(8, 2)``, ``subkeys`` (empty for the ``"keypoints"``
    handle set), ``handles``, ``deformer``, ``tracker`` and
    ``handle_keypoints``: the key point behind each key-point handle (the
    17 in order; on a split mesh shoulders and hips appear twice).  The
    handle targets of a frame are its key points at ``handle_keypoints``
    followed by the tracked subkeys.
    """

    character: Character
    mesh: Mesh
    rest_omega: np.ndarray
    subkeys: Subkeys
    handles: Handles
    deformer: TwoStepARAP
    tracker: SubkeyTracker | None
    handle_set: str
    handle_keypoints: np.ndarray
    #: The rest key points the mesh is driven by ``(17, 2)``: the character's, or on a pieced
    #: mesh with its pivots moved onto the cuts (:func:`nnsf.reshape.pieces.move_pivots`).
    #: Callers always pass key points in the character's own sense; :meth:`drive` maps them.
    rest_keypoints: np.ndarray | None = None

    def __post_init__(self):
        if self.rest_keypoints is None:
            self.rest_keypoints = np.asarray(self.character.keypoints, dtype=np.float64).copy()
        self._prepare()

    def _prepare(self) -> None:
        """What :meth:`drive` and the tabs need per frame, from the rest pose (once per rig)."""
        rest0 = np.asarray(self.character.keypoints, dtype=np.float64)
        rest1 = np.asarray(self.rest_keypoints, dtype=np.float64)
        self._moved = not np.allclose(rest1, rest0)
        torso = list(TORSO)
        self._rest_torso = rest0[torso] - rest0[torso].mean(0)  # a₀ (5, 2)
        # The chains whose pivot moved: pivot j, the next point and everything further down.
        chains = [(j, down) for j, down in DRIVE_CHAINS if not np.allclose(rest0[j], rest1[j])]
        self._pivots = np.array([j for j, _ in chains], dtype=np.int64)
        self._next = np.array([down[0] for _, down in chains], dtype=np.int64)
        self._pivot_offsets = np.array([rest1[j] - rest0[torso].mean(0) for j, _ in chains]).reshape(-1, 2)
        self._next_lengths = np.array([float(np.linalg.norm(rest1[down[0]] - rest1[j])) for j, down in chains])
        self._below = np.array([q for _, down in chains for q in down], dtype=np.int64)
        self._below_chain = np.array([i for i, (_, down) in enumerate(chains) for _ in down], dtype=np.int64)
        self._tab_motion = TabMotion(self.mesh.tabs, rest1, self.mesh.vertices) if self.mesh.tabs else None

    @property
    def moved(self) -> bool:
        """Whether the pivots differ from the character's key points."""
        return self._moved

    def drive(self, keypoints) -> np.ndarray:
        """Key points ``(..., 17, 2)`` in the character's sense -> the ones that drive this rig.

        Without moved pivots this is the identity.  With them, as the
        retargeting does (docs/method.md §12): every frame's torso pose (the
        rotation and translation fitted to the torso's key points,
        :data:`nnsf.reshape.drive.TORSO`) carries each moved pivot; the
        limb (or head) below it keeps its direction in the frame and the
        length it has from the pivot at rest, and every point further down
        moves with it.  A rigid motion of the whole figure stays exactly
        rigid.  All moved chains are handled at once (what depends on the
        rest pose alone is prepared when the rig is made).
        """
        kp = self._check(keypoints)
        if not self._moved:
            return kp

        one = kp.ndim == 2
        K = kp[None] if one else kp
        torso = list(TORSO)
        a0 = self._rest_torso
        c_t = K[:, torso].mean(1)  # (T, 2)
        b = K[:, torso] - c_t[:, None]
        ang = np.arctan2((a0[None, :, 0] * b[..., 1] - a0[None, :, 1] * b[..., 0]).sum(1),
                         (a0[None] * b).sum((1, 2)))
        c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]  # (T, 1)
        out = K.copy()
        j, nxt, v = self._pivots, self._next, self._pivot_offsets
        piv = c_t[:, None] + np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], -1)  # (T, c, 2)
        d = K[:, nxt] - K[:, j]
        d = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
        new_next = piv + d * self._next_lengths[:, None]
        out[:, j] = piv
        shift = new_next - K[:, nxt]
        out[:, self._below] = K[:, self._below] + shift[:, self._below_chain]
        return out[0] if one else out

    @classmethod
    def build(cls, character: Character, n_vertices: int = 800, handle_set: str = "subkeys",
              subkeys_per_limb: int = 4, keypoint_weight: float = 10.0, subkey_weight: float = 10.0,
              omega: np.ndarray | str = "fit", mesh: Mesh | None = None, split=False,
              fit_subkeys: bool = True, keep_offset: bool = True, propagation: str = "eq12") -> "Rig":
        """Mesh ``character`` and factorise the deformation for one handle set.

        Parameters
        ----------
        n_vertices : target mesh size (ignored when ``mesh`` is given).
        handle_set : ``"subkeys"`` or ``"keypoints"``.
        keypoint_weight, subkey_weight : handle weights w (the shape terms
            weigh 1 per triangle corner; with 10 the handles are met within
            about a pixel even in strained poses, and the normal matrices
            stay well conditioned: condition numbers about 5·10³ (step 1)
            and 9·10² (step 2) on char1 at 800 vertices, against 5·10⁵ and
            7·10⁴ with w = 100).
        omega : rest ω ``(8, 2)``, ``"fit"`` (:func:`~nnsf.reshape.limbs.fit_omega`)
            or ``"straight"``.
        mesh : reuse a mesh, e.g. to compare handle sets on the same triangles.
        split : ``False`` (connected mesh), ``True`` (limbs cut loose,
            :func:`~nnsf.reshape.mesh.split_pieces`) or ``"layered"`` (every
            segment a piece, with collars and an underlay,
            :func:`~nnsf.reshape.mesh.layer_pieces`); ignored when ``mesh``
            is given (its own ``pieces`` decide).
        fit_subkeys, keep_offset, propagation : see
            :class:`~nnsf.reshape.subkeys.SubkeyTracker`.
        """
        if handle_set not in HANDLE_SETS:
            raise ValueError(f"handle_set must be one of {HANDLE_SETS}, got {handle_set!r}")
        kp = character.keypoints
        if mesh is None:
            mesh = build_mesh(character.mask, kp, n_vertices=n_vertices, split=split,
                              texture=character.texture, extra_limbs=character.extra_limbs)
        rest_kp = kp.copy()
        if mesh.pivots is not None and not np.allclose(mesh.pivots, kp):
            # A pieced mesh's limbs turn where they meet the body (nnsf.reshape.pieces.move_pivots).
            rest_kp = np.asarray(mesh.pivots, dtype=np.float64).copy()
            kp = rest_kp
        if isinstance(omega, str):
            if omega == "fit":
                omega = fit_omega(character.mask, kp)
            elif omega == "straight":
                omega = np.tile(STRAIGHT, (N_LIMBS, 1))
            else:
                raise ValueError(f"omega must be an (8, 2) array, 'fit' or 'straight', got {omega!r}")
        omega = np.asarray(omega, dtype=np.float64).reshape(N_LIMBS, 2)
        # Joint tabs (a pieced mesh's last vertices) are not solved for: they follow their bone.
        nc = mesh.core
        Vc, Tc = mesh.vertices[:nc], mesh.triangles[mesh.core_triangles]
        Pc = mesh.pieces[mesh.core_triangles]
        if mesh.is_split:
            # Each piece is pinned by its own key points; a shoulder or hip
            # becomes one handle on each side of its seam.
            # (A piece without triangles, possible on a very coarse mesh, gets no handles.)
            used = set(np.unique(Pc).tolist())
            parts = [(pc, j) for pc, kps in enumerate(mesh.piece_keypoints) if pc in used for j in kps]
            handle_kp = np.array([j for _, j in parts], dtype=np.int64)
            handles = None
            for pc, j in parts:
                h = Handles.at_points(Vc, Tc[Pc == pc], kp[[j]], keypoint_weight)
                handles = h if handles is None else handles + h
            vp = np.zeros(nc, dtype=np.int64)
            vp[Tc.ravel()] = np.repeat(Pc, 3)
            # A limb's subkeys come from its own piece: the one holding most of its triangles.
            lc = mesh.layer[mesh.core_triangles]
            own = [np.bincount(Pc[(mesh.parts[mesh.core_triangles] == 2 + i) & (lc == 0)],
                               minlength=len(mesh.piece_names)).argmax()
                   if ((mesh.parts[mesh.core_triangles] == 2 + i) & (lc == 0)).any() else -1
                   for i in range(N_LIMBS)]
            candidates = [np.flatnonzero(vp == own[i]) if own[i] >= 0 else np.zeros(0, np.int64)
                          for i in range(N_LIMBS)]
        else:
            handle_kp = np.arange(N_JOINTS)
            handles = Handles.at_points(Vc, Tc, kp, keypoint_weight)
            candidates = None
        if handle_set == "subkeys":
            subkeys = init_subkeys(Vc, kp, omega, per_limb=subkeys_per_limb, candidates=candidates)
            handles = handles + Handles.at_vertices(nc, subkeys.vertex, subkey_weight)
            tracker = SubkeyTracker(subkeys, kp, omega, fit=fit_subkeys, keep_offset=keep_offset,
                                    propagation=propagation)
        else:
            subkeys = Subkeys(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 2)))
            tracker = None
        deformer = TwoStepARAP(Vc, Tc, handles)
        return cls(character, mesh, omega, subkeys, handles, deformer, tracker, handle_set, handle_kp, rest_kp)

    # ------------------------------------------------------------------ driving

    def _check(self, keypoints) -> np.ndarray:
        kp = np.asarray(keypoints, dtype=np.float64)
        if kp.shape[-2:] != (N_JOINTS, 2):
            raise ValueError(f"expected key points (..., {N_JOINTS}, 2), got {kp.shape}")
        return kp

    def targets(self, keypoints, omega=None) -> np.ndarray:
        """Handle targets ``(T, m, 2)`` for a clip ``(T, 17, 2)`` that starts from rest.

        Subkeys are tracked from the rest pose through every frame in order.
        """
        kp = self.drive(keypoints)
        key = kp[..., self.handle_keypoints, :]
        if self.tracker is None:
            return key
        sub = self.tracker.track(kp, omega)
        return np.concatenate([key, sub], axis=1)

    def animate(self, keypoints, omega=None, steps: int = 2) -> np.ndarray:
        """Deformed vertices ``(T, n, 2)`` (pixels) for key points ``(T, 17, 2)``."""
        V = self.deformer.deform(self.targets(keypoints, omega), steps=steps)
        return self._with_tabs(V, self.drive(keypoints))

    def _with_tabs(self, V: np.ndarray, kp: np.ndarray) -> np.ndarray:
        """The solved vertices ``(T, n_core, 2)`` with the mesh's joint tabs attached (``(T, n, 2)``)."""
        if self._tab_motion is None:
            return V
        return self._tab_motion(V, kp)

    def reset(self) -> None:
        """Restart streaming (:meth:`step`) from the rest pose."""
        if self.tracker is not None:
            self.tracker.reset()

    def step(self, keypoints, omega=None) -> np.ndarray:
        """Streaming: deform one frame ``(17, 2)`` after the previous one; returns ``(n, 2)``."""
        kp = self.drive(keypoints)
        key = kp[self.handle_keypoints]
        g = key if self.tracker is None else np.concatenate([key, self.tracker.step(kp, omega)])
        return self._with_tabs(self.deformer.deform(g)[None], kp[None])[0]
