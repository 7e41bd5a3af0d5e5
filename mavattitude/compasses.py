"""The vehicle's other magnetometers, live: each judged by a compass monitor of its own over the IMU samples.

An autopilot with several compasses sends each in its own IMU message (ArduPilot: compass 1 in RAW_IMU, 2 in
SCALED_IMU2, 3 in SCALED_IMU3; :data:`~mavattitude.sensors.units.COMPASS_INSTANCES`). The service replays
``input.message``'s; the others arrive as plain messages when the autopilot streams them (ArduPilot's
RAW_SENSORS stream carries all three). :class:`OtherCompasses` keeps each one's newest reading and, with every
IMU sample of ``input.message``, pushes that sample carrying it (repeated until the next, as the message
repeats it) into a pipeline of its own that only judges (:meth:`AttitudePipeline.push` without attitudes),
on the service's magnetic reference: the verdicts ``replay`` gives a log's other compasses (docs/vehicle.md).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from mavattitude.config import Config
from mavattitude.errors import SensorError
from mavattitude.estimation.compass import CompassEvent
from mavattitude.pipeline import AttitudePipeline
from mavattitude.sensors import units
from mavattitude.sensors.units import ImuSample


class OtherCompasses:
    """The magnetometers of the IMU messages other than ``config.input.message`` (see the module docstring)."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.own = units.COMPASS_INSTANCES.get(config.input.message)
        self._profile = units.get_profile(config.input.profile, config.input.custom)
        self._newest: dict[int, tuple[float, float, float]] = {}  # instance → its newest reading, µT
        self.judges: dict[int, AttitudePipeline] = {}  # instance → the pipeline judging it

    def reading(self, msg: Any) -> None:
        """A message from the vehicle: its compass's reading kept, if it is another compass's IMU message."""
        instance = units.COMPASS_INSTANCES.get(msg.get_type())
        if instance is None or instance == self.own:
            return
        try:
            mag = units.decode(msg, self._profile).mag_uT
        except SensorError:
            return  # not this profile's message, or implausible: that compass is not judged
        if mag is not None:
            self._newest[instance] = mag

    def push(self, sample: ImuSample, main: AttitudePipeline) -> list[tuple[int, CompassEvent]]:
        """``sample`` (of ``input.message``) into every other compass's judge, with its newest reading, on
        ``main``'s magnetic reference: the verdict changes, by instance."""
        events = []
        for instance, mag in self._newest.items():
            judge = self.judges.get(instance)
            if judge is None:
                judge = self.judges[instance] = AttitudePipeline(self.config.for_another_compass())
            if main.mag_ref_ned_uT is not None and judge.mag_ref_ned_uT is not main.mag_ref_ned_uT:
                known = main.frontend.expected_field_uT is not None
                judge.set_magnetic_reference(main.mag_ref_ned_uT, known, main.magref.measured)
                judge.mag_ref_ned_uT = main.mag_ref_ned_uT  # the same array: set again only when main's changes
            carried = dataclasses.replace(sample, mag_uT=mag, mag_repeats=True)
            events += [(instance, e) for e in judge.push(carried, attitudes=False).compass]
        return events
