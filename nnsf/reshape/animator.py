"""The reshaping pipeline in one place: built once per character, run once per frame.

    character ──► rig ──► mesh ──► deformation ──► render ──► encode
    (formats)    (rig)   (mesh)    (deform)        (render)   (video)

:class:`Animator` builds the rig, the mesh, the deformer and the underlay texture of a
:class:`~nnsf.reshape.character.Character`; :meth:`Animator.animate` retargets a motion onto it
(:func:`nnsf.reshape.drive.retarget`), deforms every frame and orders its parts
(:mod:`nnsf.reshape.depth`); :meth:`Animator.renderer` draws the frames.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nnsf.reshape import depth as depth_mod
from nnsf.reshape.character import Character
from nnsf.reshape.deform import Deformer
from nnsf.reshape.drive import biped_facing, retarget
from nnsf.reshape.mesh import build_mesh, underlay_ring, underlay_texture
from nnsf.reshape.quadruped import quadruped_orders
from nnsf.reshape.render import Renderer
from nnsf.reshape.rig import Rig

#: A character YAML's ``facing`` as a direction along x.
FACING = {"left": -1.0, "right": 1.0}
#: The page every frame is drawn on (RGB).
BACKGROUND = (255, 255, 255)


@dataclass
class Animation:
    """A driven character: key points ``(T, 17, 2)``, vertices ``(T, n, 2)``, part orders ``(T, P)``
    (back to front) and part depths ``(T, 10)`` (None without the motion's depth)."""

    keypoints: np.ndarray
    frames: np.ndarray
    orders: np.ndarray
    part_z: np.ndarray | None


class Animator:
    """One character's pipeline (module docstring).

    Parameters
    ----------
    character : the drawing.
    n_vertices : target mesh size.
    method : ``"ours"`` (key points and subkeys, the paper's) or ``"keypoints"`` (the Fig. 8 baseline).
    subkeys_per_limb, propagation : :class:`~nnsf.reshape.deform.Deformer`'s.
    """

    def __init__(self, character: Character, n_vertices: int = 800, method: str = "ours",
                 subkeys_per_limb: int = 4, propagation: str = "limb-frame"):
        self.character = character
        self.rig = Rig.build(character)
        self.mesh = build_mesh(character, self.rig, n_vertices)
        self.deformer = Deformer(self.mesh, self.rig, character.mask, method, subkeys_per_limb,
                                 propagation=propagation)
        self.underlay = underlay_texture(character.texture, character.mask, self.mesh, self.rig)
        self.facing = (FACING[character.facing] if character.facing else
                       biped_facing(character.mask, character.keypoints) if character.body == "biped" else 0.0)

    def retarget(self, motion, arms=None, head=None, source="motion", frames=None) -> np.ndarray:
        """Key points ``(T, 17, 2)`` in the drawing's pixels for a motion ``(T, 17, 2)``; ``arms`` and
        ``head`` default to the character's own choice, else ``motion``."""
        ch = self.character
        return retarget(motion, ch.keypoints, source=source, frames=frames, body=ch.body,
                        arms=arms or ch.arms or "motion", head=head or ch.head or "motion", facing=self.facing,
                        legs=ch.legs or "motion")

    def orders(self, frames: np.ndarray, motion: np.ndarray, joint_depth=None, hysteresis: float = 0.015,
               overrides=()) -> tuple[np.ndarray, np.ndarray | None]:
        """Back-to-front part orders ``(T, P)`` and part depths ``(T, 10)`` or None (docs/method.md §14).

        From the motion's joint depths ``(T, 17)`` (tie band ``hysteresis`` × its body height), or one
        static order; then the character's ``depth`` choices on every frame and the user's
        ``overrides`` (:func:`nnsf.reshape.depth.parse_overrides`) on theirs.  Extra arms are drawn
        just before the torso.
        """
        T = len(frames)
        if joint_depth is None:
            orders, z = np.tile(depth_mod.default_order(), (T, 1)), None
        else:
            z = depth_mod.part_depths(joint_depth)
            height = float(np.median(np.ptp(np.asarray(motion)[..., 1], axis=1)))
            pairs = depth_mod.part_overlaps(frames, self.mesh.triangles, np.minimum(self.mesh.parts, 9))
            orders = depth_mod.depth_orders(z, hysteresis * height, pairs=pairs)
        if self.character.body == "quadruped":
            orders = quadruped_orders(orders, self.character.keypoints)
        always = [(over, under, 0, T - 1) for over, under in self.character.depth]
        if always or overrides:
            orders = depth_mod.apply_overrides(orders, always + list(overrides))
        extra = np.arange(depth_mod.N_PARTS, self.rig.n_parts)
        if len(extra):
            at = np.argmax(orders == 0, axis=1)
            orders = np.stack([np.concatenate([o[:a], extra, o[a:]]) for o, a in zip(orders, at)])
        return orders, z

    def animate(self, motion: np.ndarray, joint_depth=None, arms=None, head=None, source="motion",
                frames=None, overrides=()) -> Animation:
        """Drive the character with a motion ``(T, 17, 2)`` (any units); ``joint_depth`` ``(T, 17)`` optional."""
        kp = self.retarget(motion, arms, head, source, frames)
        V = self.deformer.run(kp)
        orders, z = self.orders(V, motion, joint_depth, overrides=overrides)
        return Animation(kp, V, orders, z)

    def renderer(self, size) -> Renderer:
        """A :class:`~nnsf.reshape.render.Renderer` of this character for frames of ``size`` ``(H, W)``."""
        return Renderer(self.mesh, self.character.texture, self.character.mask, size, self.underlay,
                        underlay_ring(self.mesh, self.rig))


def canvas(frames: np.ndarray, margin: int = 16, shape=None) -> tuple[np.ndarray, tuple[int, int]]:
    """Offset ``(2,)`` and size ``(H, W)`` of a canvas holding every frame ``(T, n, 2)``: the box of all
    vertices plus ``margin`` pixels, even sides (video codecs want them); ``shape`` ``(H, W)`` when there
    are no frames."""
    V = np.asarray(frames, dtype=np.float64).reshape(-1, 2)
    V = V[np.isfinite(V).all(axis=1)]
    if not len(V):
        H, W = shape
        return np.zeros(2), (H + H % 2, W + W % 2)
    lo = np.floor(V.min(axis=0)) - margin
    hi = np.ceil(V.max(axis=0)) + margin
    w, h = int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)
    return -lo, (h + h % 2, w + w % 2)
