"""Test functions of the attack's dimension for comparing search algorithms.

Every function maps points (k, D) in [-1, 1]^D to values (k,) to MAXIMISE, with a known
upper bound. They are built from a numpy Generator (random shift, rotation and
layout), so one seed gives one instance:
- "ackley" and "rastrigin": the negated shifted and rotated classics, z = s Q (x - c) with
  Q a random rotation, c ~ U(-0.5, 0.5)^D the optimum and s the usual domain half-width
  (5 for Ackley, 5.12 for Rastrigin); the maximum is 0 at x = c.
- "collision": an actor's box whose 5 s track is displaced linearly by x, against the ego
  driving straight; the value is -(smallest box gap over the track) [m] until the boxes
  touch, then 1 + the fraction of time steps in contact (at most 2). Non-smooth (a minimum
  over time, a gap that is zero inside the target) with a small target region: uniform
  sampling touches the ego in well under 1 % of draws.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from advsim_ros.core.geometry import box_distance, boxes_overlap
from advsim_ros.core.search.base import SearchConfig, SearchError, run_search
from advsim_ros.core.types import FloatArray

TEST_FUNCTION_NAMES = ("ackley", "rastrigin", "collision")

_COLLISION_STEPS = 10  # time steps of the collision track (5 s at 2 Hz)
_COLLISION_DT = 0.5  # [s]
_EGO_SPEED = 8.0  # ego speed along +x [m/s]
_ACTOR_SPEED = 6.0  # nominal actor speed along +y [m/s]
_ACTOR_REACH = 6.0  # norm of each row of the displacement map at the last step [m]
_NOMINAL_MISS_TIME = 2.0  # the nominal actor crosses the ego's lane this long after the ego passed [s]


@dataclass(frozen=True, eq=False)
class TestFunction:
    """A seeded test function: values to maximise, none above `upper_bound`."""

    __test__ = False  # not a pytest test class despite the name

    name: str
    dimension: int
    upper_bound: float  # no value exceeds it (the maximum itself for ackley and rastrigin)
    evaluate: Callable[[FloatArray], FloatArray]

    def __call__(self, points: FloatArray) -> FloatArray:
        array = np.asarray(points, dtype=np.float64)
        if array.ndim != 2 or array.shape[1] != self.dimension:
            raise SearchError(f"{self.name}: points must have shape (k, {self.dimension}), got {array.shape}")
        return self.evaluate(array)


def _rotation(dimension: int, rng: np.random.Generator) -> FloatArray:
    """A uniformly random orthogonal matrix (QR of a Gaussian matrix with the sign fixed)."""
    q, r = np.linalg.qr(rng.standard_normal((dimension, dimension)))
    rotation: FloatArray = q * np.sign(np.diag(r))
    return rotation


def _shifted_rotated(dimension: int, rng: np.random.Generator, half_width: float) -> Callable[[FloatArray], FloatArray]:
    centre = rng.uniform(-0.5, 0.5, size=dimension)
    rotation = _rotation(dimension, rng)

    def transform(points: FloatArray) -> FloatArray:
        result: FloatArray = half_width * (points - centre) @ rotation.T
        return result

    return transform


def ackley(dimension: int, rng: np.random.Generator) -> TestFunction:
    transform = _shifted_rotated(dimension, rng, 5.0)

    def evaluate(points: FloatArray) -> FloatArray:
        z = transform(points)
        value: FloatArray = (
            -20.0 * np.exp(-0.2 * np.sqrt(np.mean(z * z, axis=1)))
            - np.exp(np.mean(np.cos(2.0 * np.pi * z), axis=1))
            + 20.0
            + np.e
        )
        return -value

    return TestFunction("ackley", dimension, 0.0, evaluate)


def rastrigin(dimension: int, rng: np.random.Generator) -> TestFunction:
    transform = _shifted_rotated(dimension, rng, 5.12)

    def evaluate(points: FloatArray) -> FloatArray:
        z = transform(points)
        value: FloatArray = 10.0 * dimension + np.sum(z * z - 10.0 * np.cos(2.0 * np.pi * z), axis=1)
        return -value

    return TestFunction("rastrigin", dimension, 0.0, evaluate)


def collision(dimension: int, rng: np.random.Generator) -> TestFunction:
    times = _COLLISION_DT * np.arange(1, _COLLISION_STEPS + 1)  # [s]
    ego = np.zeros((_COLLISION_STEPS, 5))
    ego[:, 0] = _EGO_SPEED * times
    ego[:, 3:] = (4.5, 1.9)
    # Nominally the actor crosses y = 0 at x = 20 m, _NOMINAL_MISS_TIME after the ego passed there.
    crossing_time = 20.0 / _EGO_SPEED + _NOMINAL_MISS_TIME
    actor = np.zeros((_COLLISION_STEPS, 5))
    actor[:, 0] = 20.0
    actor[:, 1] = _ACTOR_SPEED * (times - crossing_time)
    actor[:, 2] = np.pi / 2.0
    actor[:, 3:] = (4.5, 1.9)
    # Displacement grows over the track (like integrated controls): row norms reach _ACTOR_REACH at the end.
    directions = rng.standard_normal((2, dimension))
    directions *= _ACTOR_REACH / np.linalg.norm(directions, axis=1, keepdims=True)
    growth = times / times[-1]

    def evaluate(points: FloatArray) -> FloatArray:
        displacement = points @ directions.T  # (k, 2) at the last step [m]
        boxes = np.broadcast_to(actor, (points.shape[0], *actor.shape)).copy()
        boxes[..., :2] += growth[None, :, None] * displacement[:, None, :]
        gaps = box_distance(boxes, ego[None])  # (k, T) [m]
        touching = boxes_overlap(boxes, ego[None])
        contact = touching.mean(axis=1)
        result: FloatArray = np.where(contact > 0.0, 1.0 + contact, -gaps.min(axis=1))
        return result

    return TestFunction("collision", dimension, 2.0, evaluate)


_FACTORIES: dict[str, Callable[[int, np.random.Generator], TestFunction]] = {
    "ackley": ackley,
    "rastrigin": rastrigin,
    "collision": collision,
}


def make_test_function(name: str, dimension: int, rng: np.random.Generator) -> TestFunction:
    """The test function `name` ("ackley", "rastrigin", "collision") of this dimension, seeded by rng."""
    if name not in _FACTORIES:
        raise SearchError(f"unknown test function {name!r} (known: {', '.join(TEST_FUNCTION_NAMES)})")
    if dimension < 1:
        raise SearchError(f"{name}: dimension must be at least 1, got {dimension}")
    return _FACTORIES[name](dimension, rng)


def best_values(
    algorithm: str,
    config: SearchConfig,
    function_name: str,
    dimension: int,
    seeds: Sequence[int],
) -> FloatArray:
    """(len(seeds),) best value each seeded run of `algorithm` found on `function_name`.

    Seed s builds the function instance from Generator([s, 0]) and the search from
    Generator([s, 1]), so every algorithm meets the same instances.
    """
    from advsim_ros.core.search.registry import make_search  # the registry imports the algorithms lazily

    results = []
    for seed in seeds:
        function = make_test_function(function_name, dimension, np.random.default_rng([seed, 0]))
        search = make_search(algorithm, dimension, np.random.default_rng([seed, 1]), config)
        best = run_search(search, function)
        results.append(np.nan if best is None else best.value)
    return np.array(results, dtype=np.float64)
