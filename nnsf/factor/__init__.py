"""Factorization: the NNSF estimator and the baselines it is compared with."""
from nnsf.factor.nnsf import NNSF
from nnsf.factor.updates import weights_for_basis

__all__ = ["NNSF", "weights_for_basis"]
