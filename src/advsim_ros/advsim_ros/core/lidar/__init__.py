"""LiDAR re-simulation from the log's own data (LiDARsim-style), see docs/lidar.md.

Modules: ``sensor`` (beams, range images), ``sensor_estimation`` (the sensor model from the
sweeps), ``raycast`` (the one ray caster), ``render`` (full sweeps), ``boxes`` (actor boxes and
angular windows), ``surfels``, ``log_points`` (a log split into static and per-track points),
``background`` (static scene), ``assets`` (actor surfaces), ``optics`` (pass probabilities and
ray drop calibrated on the log), ``resim`` (``ResimModel``), ``changes`` (which actors a sweep
moves), ``rewrite`` (one sweep's removal, fill and insertion), ``ray_table`` (the rays of a sweep
being rewritten), ``model_cache`` (cache key and arrays of a model), ``config`` (``ResimConfig``),
``cache`` (atomic on-disk cache), ``errors`` (``ResimError``).
"""
