"""Motion forecasts: constant velocity (CV) or constant turn rate and velocity (CTRV) from the tracks."""

from __future__ import annotations

import numpy as np

from advsim_ros.core.types import FloatArray, IntArray
from advsim_ros.stacks.modular.config import PredictionConfig, TrackerConfig
from advsim_ros.stacks.modular.tracker import TrackSet


def predict_tracks(
    tracks: TrackSet, stamp_ns: int, future_ns: IntArray, prediction: PredictionConfig, tracker: TrackerConfig
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Future centres (N, T, 2) [m], headings (N, T) [rad] and speeds (N, T) [m/s] at future_ns (T,).

    Tracks that are not moving (see TrackSet.moving) stand still: their velocity is box jitter.
    """
    times = (np.asarray(future_ns, dtype=np.int64) - stamp_ns) * 1e-9  # (T,) [s]
    speed = tracks.speed
    moving = tracks.moving
    speed = np.where(moving, speed, 0.0)
    yaw0 = tracks.yaw
    rate = tracks.yaw_rate if prediction.model == "ctrv" else np.zeros_like(yaw0)
    rate = np.where(moving, rate, 0.0)
    yaw = yaw0[:, None] + rate[:, None] * times[None, :]
    turning = np.abs(rate) > 1e-3
    safe_rate = np.where(turning, rate, 1.0)[:, None]
    # Exact CTRV arc where turning, straight line otherwise.
    arc_x = (np.sin(yaw) - np.sin(yaw0)[:, None]) / safe_rate
    arc_y = (np.cos(yaw0)[:, None] - np.cos(yaw)) / safe_rate
    line_x = np.cos(yaw0)[:, None] * times[None, :]
    line_y = np.sin(yaw0)[:, None] * times[None, :]
    dx = speed[:, None] * np.where(turning[:, None], arc_x, line_x)
    dy = speed[:, None] * np.where(turning[:, None], arc_y, line_y)
    xy = np.stack([tracks.state[:, 0, None] + dx, tracks.state[:, 1, None] + dy], axis=-1)
    speeds = np.broadcast_to(speed[:, None], yaw.shape).copy()
    return xy, yaw, speeds
