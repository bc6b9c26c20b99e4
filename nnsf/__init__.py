"""nnsf: style-preserving 2D cartoon synthesis via non-negative style factorization.

The library part of the project: pure functions and scikit-learn estimators.
It imports none of the orchestration or experiment-tracking tools; those live
in the top-level ``flows`` package.
"""
from nnsf.factor.nnsf import NNSF

__version__ = "0.1.0"
__all__ = ["NNSF", "__version__"]
