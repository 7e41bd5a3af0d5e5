"""Every ``estimator.method`` and what it needs: the one table that names them.

A snapshot method (the rows of the kernel's table, :data:`.kernel.RULES`: ``ign``, ``cgn``, ``ml``, ``triad``)
solves Wahba's problem once per tick from the accelerometer and magnetometer (:func:`.solve`,
:func:`.solve_batch`), with the sensors' σ of the config's ``noise:``. ``fused``, the gyro-aided filter of
:mod:`.fused`, needs the gyroscope, takes its σ from its own section ``estimator.fused`` (the config refuses
a ``noise:`` with it), learns a hard-iron offset, takes the vehicle's acceleration from the GPS velocity, and
names its counters ``fused.*``. Code elsewhere asks
these rows, never compares a method's name.
"""

from __future__ import annotations

from dataclasses import dataclass

from . import kernel


@dataclass(frozen=True)
class Method:
    """What one ``estimator.method`` is and needs."""

    name: str
    snapshot: bool = True  # one Wahba solve per tick (solve, solve_batch); else a filter over every sample
    needs_gyro: bool = False
    settings_section: str | None = None  # its own config section; its σ replace the sensors' ``noise:``
    counters_prefix: str | None = None  # its own counters in the counters line are ``PREFIX.name``
    learns_mag_offset: bool = False  # it estimates a hard-iron offset (``solve --save-mag-offset``)
    uses_gps_velocity: bool = False  # it takes the vehicle's acceleration from the GPS receiver's velocity

    @property
    def sensor_noise(self) -> bool:
        """Whether it weighs by the config's ``noise:`` (a method with its own section has its own σ)."""
        return self.settings_section is None


#: ``estimator.method`` → its row.
METHODS: dict[str, Method] = {
    **{name: Method(name) for name in kernel.RULES},
    "fused": Method(
        "fused",
        snapshot=False,
        needs_gyro=True,
        settings_section="estimator.fused",
        counters_prefix="fused",
        learns_mag_offset=True,
        uses_gps_velocity=True,
    ),
}
SNAPSHOT_METHODS = tuple(name for name, m in METHODS.items() if m.snapshot)
