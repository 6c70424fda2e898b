"""LiDAR re-simulation from the log's own data (LiDARsim-style), see docs/lidar.md.

Modules: ``sensor`` (beams, range images, sensor-model estimation), ``raycast`` (the one ray
caster), ``render`` (full sweeps), ``boxes`` (actor boxes and angular windows), ``surfels``,
``background`` (static scene), ``assets`` (actor surfaces), ``resim`` (``ResimModel``),
``config`` (``ResimConfig``), ``cache`` (atomic on-disk cache).
"""
