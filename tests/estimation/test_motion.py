"""The one rule for "the specific force is gravity alone": thresholds, NaN, and the per-sample and row forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mavattitude.estimation import motion
from mavattitude.estimation.conventions import STANDARD_GRAVITY_MPS2 as G

RATE = math.radians(10.0)


@pytest.mark.parametrize(
    ("acc_norm", "gyr_norm", "expected"),
    [
        (G, 0.0, False),  # at rest
        (G * 1.029, 0.0, False),  # inside 3 % of g
        (G * 1.031, 0.0, True),  # beyond it, above g ...
        (G * 0.969, 0.0, True),  # ... and below
        (G, RATE, False),  # at the rate: not beyond it
        (G, RATE * 1.001, True),
        (math.nan, 0.0, False),  # no reading is no motion seen
    ],
)
def test_moving_is_a_turn_or_a_specific_force_off_g(acc_norm: float, gyr_norm: float, expected: bool) -> None:
    assert motion.moving(acc_norm, gyr_norm, 0.03, RATE) is expected


def test_the_rule_on_rows_is_the_rule_on_each_sample() -> None:
    rng = np.random.default_rng(7)
    acc = rng.normal(0.0, 1.0, (500, 3)) + np.array([0.0, 0.0, -G])  # |a| around g, some rows beyond 3 %
    gyr = rng.normal(0.0, RATE, (500, 3))  # about half the rows turning faster than RATE
    rows = motion.moving(motion.norm_rows(acc), motion.norm_rows(gyr), 0.03, RATE)
    pairs = zip(acc.tolist(), gyr.tolist(), strict=True)
    each = [motion.moving(motion.norm(a), motion.norm(g), 0.03, RATE) for a, g in pairs]
    assert rows.tolist() == each
    assert 0 < rows.sum() < len(rows)  # both verdicts occur: the comparison is not vacuous
    # the same operations in the same order: the norms agree to the bit, not to a tolerance
    assert motion.norm_rows(acc).tolist() == [motion.norm(a) for a in acc.tolist()]
    assert motion.norm2_rows(acc).tolist() == [motion.norm2(a) for a in acc.tolist()]
