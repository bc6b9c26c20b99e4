"""nnsf: style-preserving 2D cartoon synthesis via non-negative style factorization.

The library part of the project: pure functions and scikit-learn estimators.
It imports none of the orchestration or experiment-tracking tools; those live
in the top-level ``flows`` package.
"""
import os

__version__ = "0.1.0"
__all__ = ["NNSF", "translate", "__version__"]

# Most pixels of any image OpenCV decodes in a process that uses nnsf (nnsf.io.MAX_IMAGE_PIXELS,
# 10000 x 10000), checked on a file's header before the pixels are allocated.  OpenCV reads
# this once, when cv2 is imported, and its default (2^30) lets a 20000 x 20000 header allocate
# 1.2 GB; so it is set here, before any module of the package imports cv2 (a user's value wins).
os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", "100000000")


def __getattr__(name):
    # Lazy: `import nnsf.params` (checked before every stage) should not pay
    # for importing scikit-learn.
    if name == "NNSF":
        from nnsf.factor.nnsf import NNSF

        return NNSF
    if name == "translate":
        from nnsf.factor.style_model import translate

        return translate
    raise AttributeError(f"module 'nnsf' has no attribute {name!r}")
