"""The estimation core: pure functions on numpy arrays, no I/O, no logging, no clock.

``solve`` (one sample, plain-float fast path), ``solve_batch`` and ``solve_each`` (vectorised: the answers as
arrays, or each sample's result or refusal as ``solve`` gives it) implement the paper's
IGN (Liu et al. 2014, Eq. 34–35 with the weights of Eq. 21), CGN (equal weights), a maximum-likelihood
variant (matrix weights, reaches the Cramér–Rao bound) and TRIAD; see :mod:`.kernel` for the equations.
"""

from .batch import BatchResult, solve_batch, solve_each
from .covariance import cramer_rao_bound, predicted_covariance
from .methods import METHODS, SNAPSHOT_METHODS, Method
from .noise import NoiseModel
from .solve import SolveResult, solve

__all__ = [
    "METHODS",
    "SNAPSHOT_METHODS",
    "BatchResult",
    "Method",
    "NoiseModel",
    "SolveResult",
    "cramer_rao_bound",
    "predicted_covariance",
    "solve",
    "solve_batch",
    "solve_each",
]
