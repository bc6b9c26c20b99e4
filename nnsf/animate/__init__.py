"""Your character, your motion, a style: ``nnsf animate`` (:mod:`~nnsf.animate.animation`) and the ``animate`` stage (:mod:`~nnsf.animate.stage`)."""
