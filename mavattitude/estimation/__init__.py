"""The estimation core: pure functions on numpy arrays, no I/O, no logging, no clock."""
