"""The stack profile `advsim doctor` suggests: what it saw on the graph over how the stack was started.

The suggestion must attach the stack it was made from without edits (but for what no graph shows: a
GNSS datum, the plan's frame). So its processes are the stack's as they were started: a profile's own
entries with every key it set (paths made absolute: the suggestion is written elsewhere), or each
--stack command with its quoting kept; and what the graph showed (the LiDAR, pose and plan topics
and types) goes over a profile's keys without dropping the ones it did not discover (a datum, frames).
"""

from __future__ import annotations

import dataclasses
import json
import shlex
from typing import Any

from advsim_ros.adapters.messages import PLAN_MSGTYPES, POSE_MSGTYPES
from advsim_ros.adapters.profile import ProcessProfile, StackProfile
from advsim_ros.attack.options import StackSpec
from advsim_ros.contract import topics
from advsim_ros.contract.topics import TopicSpec

# Types an adapter converts (profile key -> type), by contract topic
ADAPTED_TYPES = {topics.ODOM.name: POSE_MSGTYPES, topics.PLAN.name: PLAN_MSGTYPES}
# Plan types in the order a plan is chosen when the stack publishes several: the contract's first
PLAN_PREFERENCE = list(dict.fromkeys(PLAN_MSGTYPES.values()))
DATUM_PLACEHOLDER = {"latitude": 0.0, "longitude": 0.0, "altitude": 0.0}


def types_for(spec: TopicSpec) -> set[str]:
    """The types a stack's endpoint for this contract topic may have (the contract's, or one an adapter converts)."""
    return {spec.msgtype, *ADAPTED_TYPES.get(spec.name, {}).values()}


def _plain(value: Any) -> Any:
    """Dataclass values as YAML-safe lists and dicts."""
    return json.loads(json.dumps(dataclasses.asdict(value)))


def _differences(values: dict[str, Any], defaults: dict[str, Any]) -> dict[str, Any]:
    """The keys of ``values`` that differ from ``defaults`` (sections compared key by key)."""
    kept: dict[str, Any] = {}
    for key, value in values.items():
        default = defaults.get(key)
        if isinstance(value, dict) and isinstance(default, dict) and value and default:
            nested = _differences(value, default)
            if nested:
                kept[key] = nested
        elif value != default:
            kept[key] = value
    return kept


def _profile_entries(profile: StackProfile) -> dict[str, Any]:
    """The keys a profile set, its processes whole (relative paths made absolute)."""
    values = _plain(profile)
    defaults = _plain(StackProfile(processes=profile.processes))
    mapping = _differences({k: v for k, v in values.items() if k not in ("processes", "folder")}, defaults)
    processes = []
    for process in profile.processes:
        entry = _differences(_plain(process), _plain(ProcessProfile(command=process.command)))
        entry = {"name": process.name, "command": process.command, **entry}
        if process.params_files:
            entry["params_files"] = [str(path) for path in profile.params_paths(process)]
        if process.cwd:
            entry["cwd"] = str(profile.cwd_path(process))
        processes.append(entry)
    return {"profile": 1, "name": profile.name, "processes": processes, **mapping}


def _command_entries(stack: StackSpec) -> dict[str, Any]:
    """--stack commands as profile processes that start them the same way."""
    specs = stack.processes()
    # a process given --ros-args without sim time (rename rules alone): the profile's use_sim_time off, and on
    # for each process that had it
    sim_time_apart = any((s.remappings or s.rename_node) and "use_sim_time" not in s.parameters for s in specs)
    processes = []
    for spec in specs:
        # the profile expands $VAR in commands; a --stack command had its $ expanded by the shell already
        entry: dict[str, Any] = {"name": spec.name, "command": shlex.join(t.replace("$", "$$") for t in spec.command)}
        remappings = {**({"__node": spec.name} if spec.rename_node else {}), **spec.remappings}
        parameters = {k: v for k, v in spec.parameters.items() if k != "use_sim_time" or sim_time_apart}
        if not (remappings or spec.params_files or spec.parameters):
            entry["ros_args"] = False  # nothing was appended to it: nothing will be
        for key, value in (("params_files", [str(p) for p in spec.params_files]), ("parameters", parameters),
                           ("remappings", remappings)):  # fmt: skip
            if value:
                entry[key] = value
        processes.append(entry)
    profile: dict[str, Any] = {"profile": 1, "name": stack.name}
    if sim_time_apart:
        profile["use_sim_time"] = False
    return {**profile, "processes": processes}


def _candidates(nodes: list[dict[str, Any]], spec: TopicSpec) -> list[tuple[str, str]]:
    side = "subscribes" if spec in topics.STACK_INPUTS else "publishes"
    return sorted({(e["topic"], e["type"]) for node in nodes for e in node[side] if e["type"] in types_for(spec)})


def _chosen_plan(candidates: list[tuple[str, str]], notes: list[str]) -> tuple[str, str] | None:
    """The plan among the stack's answers: the contract's nav_msgs/Path first, then the other types."""
    if not candidates:
        return None
    ranked = sorted(candidates, key=lambda item: (PLAN_PREFERENCE.index(item[1]), item[0]))
    if len(ranked) > 1:
        others = ", ".join(f"{topic} ({msgtype})" for topic, msgtype in ranked[1:])
        notes.append(
            f"outputs.plan: chose {ranked[0][0]} ({ranked[0][1]}) of {len(ranked)} candidates; the others: {others} "
            "(change outputs.plan.topic and type if one of them is the plan)"
        )
    return ranked[0]


def suggested_profile(nodes: list[dict[str, Any]], stack: StackSpec, timer: bool) -> tuple[dict[str, Any], list[str]]:
    """A stack profile from what the stack was seen to read and publish over how it was started, and notes
    on what it chose or could not see."""
    notes: list[str] = []
    profile = _profile_entries(stack.profile) if stack.profile is not None else _command_entries(stack)
    inputs: dict[str, Any] = profile.setdefault("inputs", {})
    outputs: dict[str, Any] = profile.setdefault("outputs", {})
    lidar = _candidates(nodes, topics.LIDAR)
    if len(lidar) == 1:
        inputs["lidar"] = {**inputs.get("lidar", {}), "topic": lidar[0][0]}
    pose = _candidates(nodes, topics.ODOM)
    if len(pose) == 1:
        topic, msgtype = pose[0]
        kind = next(key for key, value in POSE_MSGTYPES.items() if value == msgtype)
        written = inputs.get("pose", {})
        same = POSE_MSGTYPES[written.get("type", "odometry")] == msgtype
        inputs["pose"] = {**(written if same else {}), "topic": topic, "type": kind}
        if "datum" in written:
            inputs["pose"]["datum"] = written["datum"]
        elif kind == "navsatfix":
            inputs["pose"]["datum"] = dict(DATUM_PLACEHOLDER)
            notes.append("inputs.pose.datum: put the latitude, longitude and altitude of the world frame's origin")
    plan = _chosen_plan(_candidates(nodes, topics.PLAN), notes)
    if plan is not None:
        topic, msgtype = plan
        written = outputs.get("plan", {})
        same = PLAN_MSGTYPES[written.get("type", "path")] == msgtype  # a spatial_path stays one
        kind = written.get("type", "path") if same else next(k for k, v in PLAN_MSGTYPES.items() if v == msgtype)
        outputs["plan"] = {**written, "topic": topic, "type": kind}
        offered = [e["qos"] for node in nodes for e in node["publishes"] if e["topic"] == topic and e["qos"]]
        if any(qos["reliability"] == "best_effort" for qos in offered):
            outputs["plan"]["reliability"] = "best_effort"
    if timer and profile.get("timing", {}).get("mode") != "timer":
        profile["timing"] = {**profile.get("timing", {}), "mode": "timer"}
    for section in ("inputs", "outputs"):
        if not profile[section]:
            del profile[section]
    return profile, notes
