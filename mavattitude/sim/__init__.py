"""The scripted fake vehicle and everything around it.

- :mod:`.trajectory` — truth scripts in SI (NED/FRD), composable in time;
- :mod:`.scenarios` — named scripts (the paper's static case, rotation, maneuvering flight, flips) and
  sensor presets;
- :mod:`.sensors` — sensor error models (noise, bias, scale, misalignment, hard/soft iron, saturation,
  rate, jitter, drop-outs);
- :mod:`.vehicle` — the MAVLink 2 autopilot peer that flies a script and records what it hears;
- :mod:`.scoring` — angle, tilt and heading errors, output rate and latency against the truth;
- :mod:`.daemon` — `mavattitude run` as a subprocess (tests, demo, soak);
- :mod:`.soak` — the long accelerated run behind ``tools/bench.py soak``.
"""
