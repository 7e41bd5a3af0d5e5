"""What the service says: every STATUSTEXT it composes fits MAVLink's 50 characters for every input message (the
link cuts a longer one, and the ground station shows the stump)."""

from __future__ import annotations

from collections import Counter

import pytest

from mavattitude import __version__
from mavattitude.link.connection import STATUSTEXT_LEN
from mavattitude.reports import (
    CLOCKS_APART_STATUSTEXT,
    DEGENERATE_STATUSTEXT,
    REFUSAL_HINTS,
    compass_unused_statustext,
    input_lost_statustext,
    refusals_text,
    refused_statustext,
    start_statustext,
)
from mavattitude.sensors.clock import ClockEvent
from mavattitude.sensors.units import MESSAGES

# every reason a sample or tick is refused for, the longest last
REASONS = [e.value for e in ClockEvent] + ["nonfinite", "saturated_acc", "no_mag", "DegenerateGeometryError"]


@pytest.mark.parametrize("message", sorted(MESSAGES))
def test_every_statustext_fits_for_every_input_message(message):
    texts = [
        DEGENERATE_STATUSTEXT,
        CLOCKS_APART_STATUSTEXT,
        start_statustext(__version__, message),
        input_lost_statustext(message, 12.5),  # the longest a gap is said at (2.5 intervals of a 0.2 Hz stream)
        *(refused_statustext(message, Counter({reason: 1000})) for reason in REASONS),
        *(compass_unused_statustext(instance) for instance in range(3)),
    ]
    assert [t for t in texts if len(t) > STATUSTEXT_LEN] == []
    assert refused_statustext(message, Counter({"duplicate": 5, "nonfinite": 1})).endswith(" duplicate: no attitude")


def test_refusals_are_said_commonest_first_with_what_the_clock_s_reasons_mean():
    said = refusals_text(Counter({"DegenerateGeometryError": 3, "duplicate": 40, "decode": 0}))
    assert said == f"refused: duplicate 40 ({REFUSAL_HINTS['duplicate']}), DegenerateGeometryError 3"
    assert refusals_text(Counter()) == "nothing refused"
