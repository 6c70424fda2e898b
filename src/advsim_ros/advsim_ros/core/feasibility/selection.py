"""Which actors of a window are perturbed: the closest to the SDV with enough feasible candidates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from advsim_ros.core.drivable import DrivableConfig, drivable_area_for
from advsim_ros.core.feasibility.config import PerturberConfig
from advsim_ros.core.feasibility.errors import InfeasibleError
from advsim_ros.core.feasibility.feasible_set import FeasibleSet, build_feasible_set
from advsim_ros.core.feasibility.obstacles import actor_window_boxes, ego_window_boxes, window_obstacles
from advsim_ros.core.feasibility.projection import project
from advsim_ros.core.feasibility.pruning import PruningCounts
from advsim_ros.core.feasibility.rollout import PerturbedTrajectory
from advsim_ros.core.feasibility.window import Window, is_standing, window_observations
from advsim_ros.core.geometry import box_distance
from advsim_ros.core.types import ActorTrack, DrivableArea, Perturbation, Scenario


@dataclass(frozen=True)
class ActorReport:
    """Why an actor was or was not perturbed."""

    actor_id: str
    actor_class: str
    min_distance: float  # smallest gap to the SDV's box over the window's labelled frames [m]
    selected: bool
    reason: str  # "selected", or why not
    counts: PruningCounts | None  # pruning statistics when a feasible set was built
    fit_rmse: float | None  # bicycle-model fit of the logged track [m]


class TooFewActorsError(InfeasibleError):
    """select_actors found fewer perturbable actors than asked; ``reports`` says what became of every actor."""

    def __init__(self, message: str, reports: tuple[ActorReport, ...]) -> None:
        super().__init__(message)
        self.reports = reports


@dataclass(frozen=True, eq=False)
class ActorSelection:
    """The actors to perturb in a window, their feasible sets (delta block order) and a report on every actor."""

    window: Window
    sets: tuple[FeasibleSet, ...]
    reports: tuple[ActorReport, ...]

    @property
    def actor_ids(self) -> tuple[str, ...]:
        return tuple(feasible.actor_id for feasible in self.sets)

    @property
    def dimension(self) -> int:
        """Length of the concatenated delta the search works on."""
        return sum(feasible.config.perturbation_dim for feasible in self.sets)

    def project(self, delta: npt.ArrayLike) -> tuple[PerturbedTrajectory, ...]:
        return project(self.sets, delta)

    def logged_tracks(self, scenario: Scenario) -> tuple[ActorTrack, ...]:
        """The selected actors as the log has them over the window: what the identity control re-inserts."""
        first = self.window.start_frame
        stamps = scenario.frame_stamps_ns[first : first + self.window.num_steps]
        tracks = (scenario.actor(actor_id).between(int(stamps[0]), int(stamps[-1])) for actor_id in self.actor_ids)
        return tuple(track for track in tracks if track is not None)

    def project_perturbation(self, perturbation: Perturbation) -> tuple[PerturbedTrajectory, ...]:
        """A query's trajectories: none for the original scenario (empty delta), else the projection of its delta."""
        if perturbation.delta.size == 0:
            return ()
        if perturbation.actor_ids != self.actor_ids:
            raise InfeasibleError(
                f"query {perturbation.query_id} perturbs actors {list(perturbation.actor_ids)}, "
                f"the feasible sets are for {list(self.actor_ids)}"
            )
        return self.project(perturbation.delta)


def rank_actors(scenario: Scenario, window: Window, config: PerturberConfig) -> list[tuple[str, float]]:
    """Every actor present in the window with its smallest box gap to the SDV over the window [m], closest first."""
    stamps = window.stamps(scenario, config.frame_period)
    ego = ego_window_boxes(scenario, window, config)
    ranked: list[tuple[str, float]] = []
    for actor in scenario.actors:
        boxes, present = actor_window_boxes(actor, stamps)
        if np.any(present):
            ranked.append((actor.actor_id, float(np.min(box_distance(boxes[present], ego[present])))))
    ranked.sort(key=lambda item: (item[1], item[0]))
    return ranked


def select_actors(
    scenario: Scenario,
    window: Window,
    config: PerturberConfig,
    rng: np.random.Generator,
    *,
    drivable: DrivableArea | None = None,
) -> ActorSelection:
    """Perturb the config.num_actors actors closest to the SDV that keep >= config.min_feasible candidates.

    Actors are tried closest first; an actor of a class not in perturbable_classes, unlabelled at
    the window start or labelled in fewer than min_observed_steps frames is skipped, and with
    several actors one is added only if a collision-free combination with those already chosen
    exists. Raises TooFewActorsError, an InfeasibleError whose message lists every actor tried and
    whose reports say why, if fewer are found.
    """
    if drivable is None:
        drivable = drivable_area_for(scenario, DrivableConfig())  # a stored area (the nodes') wins
    obstacles = window_obstacles(scenario, window, config)
    stamps = window.stamps(scenario, config.frame_period)
    chosen: list[FeasibleSet] = []
    reports: list[ActorReport] = []
    for actor_id, gap in rank_actors(scenario, window, config):
        actor = scenario.actor(actor_id)
        steps, _ = window_observations(actor, stamps)

        def report(reason: str, counts: PruningCounts | None = None, rmse: float | None = None) -> None:
            reports.append(
                ActorReport(actor_id, actor.actor_class.value, gap, reason == "selected", reason, counts, rmse)  # noqa: B023
            )

        if len(chosen) == config.num_actors:
            report("not needed: enough actors selected")
            continue
        if actor.actor_class.value not in config.perturbable_classes:
            report(f"class {actor.actor_class.value} is not perturbable")
            continue
        standing = is_standing(actor)
        if not standing and (steps.size == 0 or steps[0] != 0):
            report("not labelled at the window start")
            continue
        if not standing and steps.size < config.min_observed_steps:
            report(f"labelled in only {steps.size} of {window.num_steps} frames")
            continue
        feasible = build_feasible_set(scenario, window, actor_id, config, rng, drivable=drivable, obstacles=obstacles)
        rmse = feasible.reference.fit.position_rmse
        if feasible.size < config.min_feasible:
            report(f"only {feasible.size} feasible candidates (< {config.min_feasible})", feasible.counts, rmse)
            continue
        if chosen:
            try:
                zeros = np.zeros(config.perturbation_dim * (len(chosen) + 1))
                project([*chosen, feasible], zeros)
            except InfeasibleError:
                report("every candidate collides with the actors already selected", feasible.counts, rmse)
                continue
        chosen.append(feasible)
        report("selected", feasible.counts, rmse)
    selection = ActorSelection(window=window, sets=tuple(chosen), reports=tuple(reports))
    if len(chosen) < config.num_actors:
        lines = "; ".join(f"{r.actor_id}: {r.reason}" for r in reports) or "no actor is labelled in the window"
        raise TooFewActorsError(
            f"scenario {scenario.scenario_id} window at frame {window.start_frame}: found {len(chosen)} of "
            f"{config.num_actors} perturbable actors ({lines})",
            tuple(reports),
        )
    return selection
