"""mavattitude: an independent accelerometer + magnetometer attitude estimate for a MAVLink vehicle.

The estimator is the improved quaternion Gauss-Newton (IGN) algorithm of Liu, Li, Wang and Liu (2014).
"""

__version__ = "0.1.0"
