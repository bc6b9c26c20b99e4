"""Reshaping drawn characters (docs/method.md §10-§14, the paper's §5).

A drawn character (:class:`Character`: texture, mask, 17 key points) is
triangulated (:func:`build_mesh`), given a quadratic Bézier curve per limb
(:mod:`~nnsf.reshape.limbs`, Eq. 9-10) and subkey points along those curves
(:mod:`~nnsf.reshape.subkeys`, Eq. 11-14), and deformed frame by frame with
the two-step ARAP of Igarashi et al. 2005 (:class:`TwoStepARAP`), factorised
once per character and handle set.  :class:`Rig` assembles all of it;
:mod:`~nnsf.reshape.metrics` scores the result (docs/method.md §15.7).

Around the rig: :mod:`~nnsf.reshape.drive` maps any 17-point motion onto a
drawing (bone directions from the motion, lengths from the drawing),
:mod:`~nnsf.reshape.depth` orders the parts back to front from the source's
depth, :mod:`~nnsf.reshape.render` rasterises the textured mesh and writes
PNG/GIF/MP4, :mod:`~nnsf.reshape.stage` is the ``reshape`` stage,
:mod:`~nnsf.reshape.evaluation` the docs/method.md §15.7 evaluation and
:mod:`~nnsf.reshape.kenney` the real-frame check.  The default mesh is
**layered** (:func:`~nnsf.reshape.mesh.layer_pieces`): every limb segment a
piece with a straight cut and a joint cap, so no joint folds.

For a renderer: ``rig.animate(keypoints)`` gives vertices ``(T, n, 2)``;
``rig.mesh.triangles`` ``(t, 3)``, ``rig.mesh.parts`` ``(t,)`` (ids into
:data:`PARTS`) and the texture coordinates ``rig.mesh.vertices`` (rest
positions in texture pixels) complete the picture.  All coordinates are
pixels, x right, y down.
"""
from nnsf.reshape import metrics
from nnsf.reshape.arap import Handles, TwoStepARAP, barycentric
from nnsf.reshape.character import (
    Character, MaskComponentsWarning, load_animated_drawings, load_character, read_character,
    stick_figure, write_character,
)
from nnsf.reshape.limbs import (
    LIMB_NAMES, LIMB_PAIRS, STRAIGHT, bezier, control_from_omega, control_points, fit_omega,
    interpolate_omega, limb_curves, omega_from_control,
)
from nnsf.reshape.layers import build_mesh, joint_cuts, layer_pieces
from nnsf.reshape.mesh import Mesh, label_parts, triangulate_mask
from nnsf.reshape.parts import PARTS, SEGMENTS
from nnsf.reshape.depth import default_order, depth_metric, depth_orders, part_depths, part_overlaps
from nnsf.reshape.drive import read_motion, retarget
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.video import write_gif, write_mp4, write_png_frames
from nnsf.reshape.rig import HANDLE_SETS, Rig
from nnsf.reshape.subkeys import SubkeyTracker, Subkeys, closest_on_bezier, init_subkeys, propagate

__all__ = [
    "Character", "MaskComponentsWarning", "load_animated_drawings", "load_character", "read_character",
    "stick_figure", "write_character",
    "PARTS", "SEGMENTS", "Mesh", "build_mesh", "joint_cuts", "label_parts", "layer_pieces", "triangulate_mask",
    "default_order", "depth_metric", "depth_orders", "part_depths", "part_overlaps",
    "read_motion", "retarget", "MeshRenderer", "write_gif", "write_mp4", "write_png_frames",
    "LIMB_NAMES", "LIMB_PAIRS", "STRAIGHT", "bezier", "control_from_omega", "control_points", "fit_omega",
    "interpolate_omega", "limb_curves", "omega_from_control",
    "SubkeyTracker", "Subkeys", "closest_on_bezier", "init_subkeys", "propagate",
    "Handles", "TwoStepARAP", "barycentric",
    "HANDLE_SETS", "Rig", "metrics",
]
