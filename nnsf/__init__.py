"""nnsf: style-preserving 2D cartoon synthesis via non-negative style factorization.

The library part of the project: pure functions and scikit-learn estimators.
It imports none of the orchestration or experiment-tracking tools; those live
in the top-level ``flows`` package.
"""
__version__ = "0.1.0"
__all__ = ["NNSF", "translate", "__version__"]


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
