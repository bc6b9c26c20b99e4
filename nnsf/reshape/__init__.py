"""Reshaping drawn characters (docs/method.md §10-§14, the paper's §5).

One pipeline, each step a module, built once per character and run once per frame:

1. :mod:`~nnsf.reshape.character`: the drawing, its mask and joints, and an optional character
   YAML (per-character choices);
2. :mod:`~nnsf.reshape.rig`: the parts (triangle labels, the joints that join them, the layers of
   limbs drawn over the body) and :mod:`~nnsf.reshape.depth` (their order, per frame);
3. :mod:`~nnsf.reshape.mesh`: one connected triangulation of the silhouette, cut along the seams
   between parts except at the joints;
4. :mod:`~nnsf.reshape.deform`: the paper's deformation: Bézier limbs (Eq. 9-10,
   :mod:`~nnsf.reshape.limbs`), subkeys (Eq. 11-14, :mod:`~nnsf.reshape.subkeys`) and two-step
   ARAP (:mod:`~nnsf.reshape.arap`);
5. :mod:`~nnsf.reshape.render`: every pixel from a deformed triangle of the drawing, parts
   composited back to front;
6. :mod:`~nnsf.reshape.video`: encoding.

:class:`~nnsf.reshape.animator.Animator` runs the six.  Around them: :mod:`~nnsf.reshape.drive`
retargets a motion onto a drawing, :mod:`~nnsf.reshape.metrics` and :mod:`~nnsf.reshape.artefacts`
measure the result, :mod:`~nnsf.reshape.evaluation` and :mod:`~nnsf.reshape.stage` are the
evaluation and the ``reshape`` stage.  Coordinates are pixels, x right, y down.
"""
