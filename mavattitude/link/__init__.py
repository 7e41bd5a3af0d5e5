"""The MAVLink edge: the only package that imports pymavlink."""
