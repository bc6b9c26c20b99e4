"""Reshaping drawn characters (docs/method.md §10-§14, the paper's §5).

One pipeline, each step a module, built once per character and run once per frame:
:mod:`~nnsf.reshape.character` (the drawing, its mask and joints, an optional character YAML) →
:mod:`~nnsf.reshape.rig` (the parts, the joints that join them, the layers of limbs drawn over the
body; :mod:`~nnsf.reshape.depth` orders them per frame) → :mod:`~nnsf.reshape.mesh` (one connected
triangulation, cut between parts except at the joints) → :mod:`~nnsf.reshape.deform` (the paper's
Bézier limbs, subkeys and two-step ARAP: :mod:`~nnsf.reshape.limbs`, :mod:`~nnsf.reshape.subkeys`,
:mod:`~nnsf.reshape.arap`) → :mod:`~nnsf.reshape.render` (every pixel from a deformed triangle of
the drawing, parts composited back to front) → :mod:`~nnsf.reshape.video` (encoding).

:class:`~nnsf.reshape.animator.Animator` runs the six.  Around them: :mod:`~nnsf.reshape.drive`
retargets a motion onto a drawing, :mod:`~nnsf.reshape.metrics` and :mod:`~nnsf.reshape.artefacts`
measure the result, :mod:`~nnsf.reshape.evaluation` and :mod:`~nnsf.reshape.stage` are the
evaluation and the ``reshape`` stage.  Coordinates are pixels, x right, y down.
"""
