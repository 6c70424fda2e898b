"""A scenario bag (an attack's OUTDIR/adversarial) as ASAM OpenSCENARIO 1.x XML, with the scenariogeneration package.

What is written (docs/outputs.md, "OpenSCENARIO"):

- the ego ("ego") and every actor of the bag (named by its actor id) as entities: vehicles as
  Vehicle (car, van or truck by length; cyclists as bicycle), pedestrians as Pedestrian, others
  as MiscObject (obstacle), with the bag's box sizes. Perturbed actors carry the property
  ``advsim:perturbed = true``.
- Init: each entity teleported to its first pose and given its initial speed [m/s] (finite
  differences along its heading); the ego also gets its logged route (AssignRouteAction,
  a waypoint every ``route_step`` seconds and at the end).
- One story whose act starts at simulation time 0: every entity follows its timed polyline
  (FollowTrajectoryAction, following mode "position", absolute time reference): one vertex per
  frame of the bag, time = frame stamp - first frame stamp [s], position in the bag's world
  frame [m, rad]. The ego's is its logged (human) trajectory; perturbed actors' are their
  perturbed trajectories, the others as logged. The storyboard stops at the last frame's time.
- Reference points as OpenSCENARIO defines them: the ego's is the ego frame's origin (below the
  rear axle), its bounding box ``ego_geometry.forward_offset`` ahead; an actor's is its box centre on the
  ground (box centre z - height / 2), its bounding box centred above it.
- No road network: logs without a map have none, and a LogicFile is not written. An Argoverse 2
  map would need a converter from its lane graph to OpenDRIVE (see docs/outputs.md).

The XML is validated against the XSD that ships with scenariogeneration before it is written.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.contract.tracks import TrackRecord
from advsim_ros.core.atomic import atomic_file
from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, IntArray, Scenario, ScenarioError
from advsim_ros.io.bag import BagConfig, read_scenario_bag
from advsim_ros.viz.attack_view import bag_perturbed_ids

NS_PER_S = 1_000_000_000
EGO = "ego"
PERTURBED_PROPERTY = "advsim:perturbed"
XSD_NAME = "OpenSCENARIO_1_3_1.xsd"  # scenariogeneration writes OpenSCENARIO 1.3 by default


class ExportError(ScenarioError):
    """A scenario that cannot be exported, or XML that does not validate; the message says why."""


@dataclass(frozen=True)
class ExportConfig:
    """Choices of the export that the data does not fix."""

    route_step: float = 1.0  # spacing of the ego route's waypoints in time [s]
    truck_length: float = 8.0  # vehicles at least this long are trucks [m]
    van_length: float = 5.5  # vehicles at least this long (and shorter than a truck) are vans [m]
    author: str = "advsim_ros"

    def __post_init__(self) -> None:
        if not (self.route_step > 0.0 and math.isfinite(self.route_step)):
            raise ExportError(f"ExportConfig.route_step: must be a positive time [s], got {self.route_step}")
        if not 0.0 < self.van_length < self.truck_length:
            raise ExportError("ExportConfig: need 0 < van_length < truck_length [m]")


@dataclass(frozen=True, eq=False)
class TimedTrajectory:
    """An entity's trajectory as written to (or read back from) the XML."""

    times: FloatArray  # (T,) seconds after the first frame [s]
    xyzh: FloatArray  # (T, 4) reference point x, y, z [m] and heading [rad]


@dataclass(frozen=True)
class ExportReport:
    path: Path
    entities: int
    perturbed: tuple[str, ...]
    vertices: int
    warnings: tuple[str, ...] = field(default_factory=tuple)

    def describe(self) -> str:
        text = (
            f"wrote {self.path}: OpenSCENARIO 1.3, {self.entities} entities (ego and actors; perturbed: "
            f"{', '.join(self.perturbed) or 'none'}), {self.vertices} trajectory vertices, validated against {XSD_NAME}"
        )
        return "\n".join([text, *self.warnings])


def _xosc() -> Any:
    from scenariogeneration import xosc  # imported here: the package is needed only by this export

    return xosc


@functools.cache
def schema() -> Any:
    """The OpenSCENARIO XSD that ships with scenariogeneration, as an xmlschema schema."""
    from importlib import metadata

    import xmlschema

    # the wheel installs its schemas/ folder beside the package, not inside it: ask its file list
    files = [entry for entry in metadata.files("scenariogeneration") or () if entry.name == XSD_NAME]
    path = Path(str(files[0].locate())) if files else None
    if path is None or not path.is_file():
        raise ExportError(f"the OpenSCENARIO schema {XSD_NAME} is missing from the scenariogeneration package")
    return xmlschema.XMLSchema(str(path))


def validate(xml: bytes | Path) -> None:
    """ExportError with the first violation unless the XML validates against the OpenSCENARIO XSD."""
    import xmlschema
    from lxml import etree

    try:
        tree = etree.parse(str(xml)) if isinstance(xml, Path) else etree.fromstring(xml).getroottree()
    except (OSError, etree.XMLSyntaxError) as error:
        raise ExportError(f"not readable XML: {error}") from None
    try:
        schema().validate(tree)
    except xmlschema.XMLSchemaValidationError as error:
        raise ExportError(f"the XML does not validate against {XSD_NAME}: {error.reason} at {error.path}") from None


def _times(stamps_ns: IntArray, start_ns: int) -> list[float]:
    return [(int(stamp) - start_ns) / NS_PER_S for stamp in stamps_ns.tolist()]


def _actor_reference(actor: ActorTrack) -> FloatArray:
    """(T, 4) the actor's reference point (box centre on the ground) and heading."""
    ground = actor.centers[:, 2] - actor.height / 2.0
    return np.column_stack([actor.centers[:, 0], actor.centers[:, 1], ground, actor.yaws])


def _ego_reference(scenario: Scenario) -> FloatArray:
    return np.column_stack([scenario.ego.xy, scenario.ego.poses[:, 2, 3], scenario.ego.yaws])


def _initial_speed(stamps_ns: IntArray, xyzh: FloatArray) -> float:
    """Speed along the heading at the first state [m/s] (finite differences; 0 for a single state)."""
    if stamps_ns.shape[0] < 2:
        return 0.0
    track = ActorTrack("speed", ActorClass.OTHER, np.ones(3), stamps_ns, xyzh[:, :3], xyzh[:, 3])
    return float(TrackRecord.from_actor_track(track).velocity[0])


def _entity(xosc: Any, name: str, actor_class: ActorClass, size: Sequence[float], center_x: float, perturbed: bool,
            config: ExportConfig) -> Any:  # fmt: skip
    length, width, height = (float(v) for v in size)
    box = xosc.BoundingBox(width, length, height, center_x, 0.0, height / 2.0)
    if actor_class == ActorClass.PEDESTRIAN:
        entity = xosc.Pedestrian(name, 75.0, xosc.PedestrianCategory.pedestrian, box, model="pedestrian")
    elif actor_class == ActorClass.OTHER:
        entity = xosc.MiscObject(name, 100.0, xosc.MiscObjectCategory.obstacle, box)
    else:
        if actor_class == ActorClass.CYCLIST:
            category = xosc.VehicleCategory.bicycle
        elif length >= config.truck_length:
            category = xosc.VehicleCategory.truck
        elif length >= config.van_length:
            category = xosc.VehicleCategory.van
        else:
            category = xosc.VehicleCategory.car
        # axles only to satisfy the schema: a wheelbase of 60 % of the length, wheels of 0.6 m [m]
        front = xosc.Axle(0.5, 0.6, width * 0.85, length * 0.6, 0.3)
        rear = xosc.Axle(0.0, 0.6, width * 0.85, 0.0, 0.3)
        entity = xosc.Vehicle(name, category, box, front, rear, 70.0, 10.0, 10.0)
    if perturbed:
        entity.add_property(PERTURBED_PROPERTY, "true")
    return entity


def _position(xosc: Any, row: Sequence[float]) -> Any:
    x, y, z, h = (float(v) for v in row)
    return xosc.WorldPosition(x=x, y=y, z=z, h=h, p=0.0, r=0.0)


def _follow(xosc: Any, name: str, times: Sequence[float], xyzh: FloatArray) -> Any:
    trajectory = xosc.Trajectory(f"{name}_trajectory", False)
    trajectory.add_shape(xosc.Polyline(list(times), [_position(xosc, row) for row in xyzh.tolist()]))
    action = xosc.FollowTrajectoryAction(
        trajectory, xosc.FollowingMode.position, xosc.ReferenceContext.absolute, 1.0, 0.0
    )
    event = xosc.Event(f"{name}_follows", xosc.Priority.override)
    event.add_action(f"{name}_follow_trajectory", action)
    event.add_trigger(
        xosc.ValueTrigger(
            f"{name}_start", 0.0, xosc.ConditionEdge.none, xosc.SimulationTimeCondition(0.0, xosc.Rule.greaterOrEqual)
        )
    )
    maneuver = xosc.Maneuver(f"{name}_maneuver")
    maneuver.add_event(event)
    group = xosc.ManeuverGroup(f"{name}_group")
    group.add_actor(name)
    group.add_maneuver(maneuver)
    return group


def _route(xosc: Any, times: Sequence[float], xyzh: FloatArray, step: float) -> Any:
    route = xosc.Route("ego_logged_route")
    picked = [0]
    for index, time in enumerate(times):
        if time - times[picked[-1]] >= step - 1e-9:
            picked.append(index)
    if picked[-1] != len(times) - 1:
        picked.append(len(times) - 1)
    for index in picked:
        route.add_waypoint(_position(xosc, xyzh[index].tolist()), xosc.RouteStrategy.shortest)
    return xosc.AssignRouteAction(route)


def scenario_xml(scenario: Scenario, perturbed_ids: Sequence[str], config: ExportConfig | None = None) -> bytes:
    """The scenario as OpenSCENARIO 1.3 XML bytes (validated); see the module docstring for what it holds."""
    xosc = _xosc()
    from scenariogeneration import helpers

    config = config or ExportConfig()
    if scenario.num_frames < 2:
        raise ExportError(f"scenario {scenario.scenario_id}: needs at least 2 frames for a trajectory")
    if any(actor.actor_id == EGO for actor in scenario.actors):
        raise ExportError(f"scenario {scenario.scenario_id}: an actor is named {EGO!r}, the ego's entity name")
    start = int(scenario.frame_stamps_ns[0])
    moved = set(perturbed_ids)
    missing = sorted(moved - {actor.actor_id for actor in scenario.actors})
    if missing:
        raise ExportError(f"scenario {scenario.scenario_id}: perturbed actors {missing} are not in the bag")
    entities = xosc.Entities()
    init = xosc.Init()
    act = xosc.Act(
        "advsim_replay",
        xosc.ValueTrigger(
            "act_start", 0.0, xosc.ConditionEdge.none, xosc.SimulationTimeCondition(0.0, xosc.Rule.greaterOrEqual)
        ),
    )
    step = xosc.TransitionDynamics(xosc.DynamicsShapes.step, xosc.DynamicsDimension.time, 0.0)
    rows: list[tuple[str, ActorClass, Sequence[float], float, IntArray, FloatArray]] = [
        (EGO, ActorClass.VEHICLE, scenario.ego_geometry.size.tolist(), scenario.ego_geometry.forward_offset,
         scenario.frame_stamps_ns,
         _ego_reference(scenario)),
    ]  # fmt: skip
    rows += [
        (actor.actor_id, actor.actor_class, actor.size.tolist(), 0.0, actor.stamps_ns, _actor_reference(actor))
        for actor in scenario.actors
    ]
    vertices = 0
    for name, actor_class, size, center_x, stamps, xyzh in rows:
        entities.add_scenario_object(name, _entity(xosc, name, actor_class, size, center_x, name in moved, config))
        init.add_init_action(name, xosc.TeleportAction(_position(xosc, xyzh[0].tolist())))
        init.add_init_action(name, xosc.AbsoluteSpeedAction(_initial_speed(stamps, xyzh), step))
        times = _times(stamps, start)
        if name == EGO:
            init.add_init_action(name, _route(xosc, times, xyzh, config.route_step))
        if len(times) >= 2:  # an actor seen once stays where it was teleported
            act.add_maneuver_group(_follow(xosc, name, times, xyzh))
            vertices += len(times)
    story = xosc.Story("advsim_story")
    story.add_act(act)
    duration = (int(scenario.frame_stamps_ns[-1]) - start) / NS_PER_S
    stop = xosc.ValueTrigger(
        "scenario_end", 0.0, xosc.ConditionEdge.rising,
        xosc.SimulationTimeCondition(duration, xosc.Rule.greaterOrEqual), "stop",
    )  # fmt: skip
    storyboard = xosc.StoryBoard(init, stop)
    storyboard.add_story(story)
    document = xosc.Scenario(
        f"advsim {scenario.scenario_id}", config.author, xosc.ParameterDeclarations(), entities, storyboard,
        xosc.RoadNetwork(), xosc.Catalog(),
    )  # fmt: skip
    xml: bytes = helpers.prettify(document.get_element(), encoding="utf-8")
    validate(xml)
    return xml


def export_openscenario(
    bag: Path,
    output: Path,
    *,
    overwrite: bool = False,
    config: ExportConfig | None = None,
    bag_config: BagConfig | None = None,
) -> ExportReport:
    """Write a scenario bag (e.g. OUTDIR/adversarial; its layout ``bag_config``) as an OpenSCENARIO file,
    validated, atomically."""
    output = Path(output)
    if output.exists() and not overwrite:
        raise ExportError(f"{output} exists (pass --overwrite to replace it)")
    scenario = read_scenario_bag(Path(bag), config=bag_config, load_sweeps=False)
    perturbed = bag_perturbed_ids(Path(bag))
    xml = scenario_xml(scenario, perturbed, config)
    with atomic_file(output, "wb") as stream:
        stream.write(xml)
    warnings = () if scenario.road_map is None else (
        "note: the bag's road map is not exported (no OpenDRIVE converter; see docs/outputs.md)",
    )  # fmt: skip
    vertices = scenario.num_frames + sum(a.stamps_ns.shape[0] for a in scenario.actors if a.stamps_ns.shape[0] >= 2)
    return ExportReport(output, 1 + len(scenario.actors), tuple(perturbed), vertices, warnings)


def read_trajectories(path: Path) -> dict[str, TimedTrajectory]:
    """Entity name -> its FollowTrajectoryAction polyline, read back from the XML with lxml (not scenariogeneration)."""
    from lxml import etree

    tree = etree.parse(str(path))
    found: dict[str, TimedTrajectory] = {}
    for group in tree.iterfind(".//ManeuverGroup"):
        names = [ref.get("entityRef") for ref in group.iterfind("./Actors/EntityRef")]
        polylines = group.findall(".//FollowTrajectoryAction//Shape/Polyline")
        if len(names) != 1 or len(polylines) != 1:
            continue
        times, rows = [], []
        for vertex in polylines[0].iterfind("./Vertex"):
            position = vertex.find("./Position/WorldPosition")
            if position is None:
                raise ExportError(f"{path}: a vertex of {names[0]} has no WorldPosition")
            times.append(float(vertex.get("time", "nan")))
            rows.append([float(position.get(key, "0")) for key in ("x", "y", "z", "h")])
        found[str(names[0])] = TimedTrajectory(np.array(times), np.array(rows, dtype=np.float64))
    return found


def perturbed_entities(path: Path) -> set[str]:
    """Names of the entities the XML marks as perturbed."""
    from lxml import etree

    tree = etree.parse(str(path))
    marked = set()
    for scenario_object in tree.iterfind(".//Entities/ScenarioObject"):
        for prop in scenario_object.iterfind(".//Properties/Property"):
            if prop.get("name") == PERTURBED_PROPERTY and prop.get("value") == "true":
                marked.add(str(scenario_object.get("name")))
    return marked
