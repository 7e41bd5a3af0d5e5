"""The sensor front end: MAVLink units, mounting, calibration, filtering and resampling."""
