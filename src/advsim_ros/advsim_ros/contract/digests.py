"""Digests of what a stack was sent and what it answered during one query, in log time.

The scenario player feeds them as the query runs; ``advsim attack`` recomputes the input digest
of the recorded query when it writes the adversarial bag, which proves the bag holds exactly
what the stack saw. Sim-time stamps are left out (they differ per query by design), so two
evaluations of the same perturbation have equal digests exactly when the stack got the same
bytes and answered the same plans.
"""

from __future__ import annotations

from advsim_ros.contract import names
from advsim_ros.contract.codec import ContractError, Msg, after_stamp, decode, encode
from advsim_ros.contract.plan import plan_from_path
from advsim_ros.core.digest import Digest
from advsim_ros.core.types import FloatArray


class InputDigest:
    """Every frame's odometry, ego pose and LiDAR sweep (CDR after the header stamp)."""

    def __init__(self) -> None:
        self._digest = Digest("stack inputs")

    def frame(self, log_stamp_ns: int, odometry_cdr: bytes, world_T_ego: FloatArray) -> None:
        self._digest.integer(log_stamp_ns)
        self._digest.raw(odometry_cdr)
        self._digest.array(world_T_ego)

    def sweep(self, cloud_cdr: bytes) -> None:
        # as the sender serialized it: a sample received over shared memory comes padded to a multiple of 4 bytes
        # (an RTPS DATA submessage's length), which encoding the same cloud again does not give
        canonical = encode(decode(cloud_cdr, names.POINTCLOUD2))
        self._digest.raw(after_stamp(canonical))

    def hexdigest(self) -> str:
        return self._digest.hexdigest()


class PlanDigest:
    """Every plan the stack answered, moved from sim time to log time."""

    def __init__(self) -> None:
        self._digest = Digest("stack plans")

    def plan(self, path: Msg, sim_offset_ns: int) -> None:
        try:
            plan = plan_from_path(path, sim_offset_ns)
        except ContractError as error:
            self._digest.text(f"unreadable plan: {error}")
            return
        self._digest.array(plan.stamps_ns)
        self._digest.array(plan.xy)
        self._digest.array(plan.yaws)

    def hexdigest(self) -> str:
        return self._digest.hexdigest()
