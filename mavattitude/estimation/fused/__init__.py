"""The gyro-aided ("fused") attitude filter, by concern: :mod:`.settings`, the error-state filter
(:mod:`.ekf`, on :mod:`.mat3` algebra), rest detection (:mod:`.rest`), magnetic checks and learning
(:mod:`.magnetic`), and :mod:`.filter`, which runs them on each sample."""

from .filter import COUNTERS, FusedEstimate, FusedFilter
from .settings import FusedSettings

__all__ = ["COUNTERS", "FusedEstimate", "FusedFilter", "FusedSettings"]
