"""The campaign YAML: what to attack, with what, how often; checked whole before anything starts.

    scenarios:                      # each entry: bag | bags | synthetic, and which windows
      - bag: logs/kitti_0000        # a scenario bag (paths are relative to this file)
        windows: {curated: 3}       # the 3 curated windows of highest SDV collision rate (default 1)
      - bags: logs/                 # every scenario bag in a folder
        windows: all                # every candidate window (params/curation.yaml step)
        bag_params: my_bag.yaml     # bags recorded your way: their layout (bag | bags; default `--bag-params`)
      - synthetic: {seeds: [0, 1]}  # synthetic street logs, written into OUTDIR/logs
        windows: {starts: [0]}      # explicit first frames
      - synthetic: {seed_range: [0, 50], families: [lead_brake, cut_in, crossing]}  # scene families
    stacks: [reference, learned, {name: mine, command: "my_stack --fast", remap: {/plan: /my/plan}}]
    algorithms: {bo: 75, ga: 500}   # algorithm: query budget
    actors: [1]                     # actors perturbed at once (Table 4: [1, 2, 3, 4, 5])
    objectives: [M5]                # M0..M5, closest_distance, max_margin (Table 6)
    loops: [open]                   # open (the paper's), closed (the ego drives the plans), or both
    reactive_actors: false          # closed-loop attacks: moving vehicles react to the ego (IDM along their paths)
    seeds: [0]
    reruns: 1                       # re-evaluations of each attack's best query (reproducibility)
    transfer: true                  # replay every found failure on every other stack (Table 3)
    failure: {collision: true, adversarial_loss_above: null}   # what the regression suite takes
    parameters: {perturber: {num_candidates: 2000}}            # node parameters for every attack

Every combination of scenario window, stack, algorithm, actors, objective and seed is one
attack; a problem is reported as one line naming the key (CampaignError).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TypedDict

import yaml

from advsim_ros import graph
from advsim_ros.attack.checks import check_stack_command
from advsim_ros.attack.options import AttackOptions, StackSpec, default_params_dir
from advsim_ros.core.attack_summary import FindingRecord, Score, metric
from advsim_ros.core.curation import CurationConfig, curate_windows, load_curation_config
from advsim_ros.core.episode import WindowConfig
from advsim_ros.core.objective import PRESET_NAMES
from advsim_ros.core.search.registry import ALGORITHM_NAMES, accept_algorithm
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag import BagConfig, bag_layout_json, bag_layout_of, load_bag_config, read_scenario_bag

TOP_KEYS = (
    "scenarios", "stacks", "algorithms", "actors", "objectives", "seeds", "loops", "reactive_actors", "reruns",
    "transfer", "failure", "parameters", "plan_timeout", "storage",
)  # fmt: skip
SCENARIO_KEYS = ("bag", "bags", "synthetic", "windows", "bag_params")
STACK_KEYS = ("name", "command", "remap", "remap_mode", "params")
FAILURE_KEYS = ("collision", "adversarial_loss_above", "exclude")
# what keeps a found collision from counting as the stack's failure (attack.controls finding's reasons)
EXCLUSIONS = ("flaky", "original_flaky", "sim_dominated", "unavoidable")
SYNTHETIC_KEYS = ("seeds", "seed_range", "families")


class CampaignError(ScenarioError):
    """A campaign configuration that cannot run; the message names the key and the problem."""


@dataclass(frozen=True)
class ScenarioSource:
    """One scenario log of the campaign and the windows to attack in it."""

    name: str  # unique within the campaign: the bag folder's name (or synthetic_seedN, synthetic_FAMILY_seedN)
    bag: Path
    windows: Any  # "curated" | "all" | {"curated": k} | {"starts": [...]}
    synthetic_seed: int | None = None  # written into OUTDIR/logs before the attacks when not None
    synthetic_family: str = "street"  # the synthetic log's scene family (io.synthetic_families)
    bag_config: BagConfig | None = None  # the bag's layout (bag_params, --bag-params); None: the contract's


class Found(TypedDict, total=False):
    """What FailureRule.counts reads of a journal entry of an attack (campaign.journal.AttackEntry)."""

    adversarial: Score | None
    finding: FindingRecord | None


@dataclass(frozen=True)
class FailureRule:
    """Which adversarial scenarios count as failures (and go into the regression suite)."""

    collision: bool = True  # a collision up to 5 s
    adversarial_loss_above: float | None = None  # or L_adv above this value
    exclude: tuple[str, ...] = EXCLUSIONS  # a collision with any of these reasons is not the stack's failure

    def excluded(self, finding: FindingRecord | None) -> list[str]:
        """The reasons of a finding (attack.controls) this rule excludes it for, e.g. ['unavoidable: ...']."""
        reasons = (finding.get("excluded") if finding else None) or []
        return [reason for reason in reasons if str(reason).split(":")[0] in self.exclude]

    def counts(self, entry: Found) -> bool:
        """Whether a campaign journal entry of an attack holds a failure of its stack."""
        return self.failed(entry.get("adversarial"), entry.get("finding"))

    def failed(self, score: Mapping[str, object] | None, finding: FindingRecord | None = None) -> bool:
        if not score:
            return False
        if self.collision and metric(score, "collision_5s") > 0.5 and not self.excluded(finding):  # NaN: no
            return True
        loss = metric(score, "adversarial_loss")
        return self.adversarial_loss_above is not None and loss > self.adversarial_loss_above


@dataclass(frozen=True)
class AttackPlan:
    """One attack of the campaign: everything needed to run it in another process (JSON)."""

    key: str  # unique, also the attack's folder name under OUTDIR/attacks
    scenario: str
    bag: str
    window_start: int
    stack: str  # the stack's name in the campaign
    stack_entry: Any  # the config entry that builds its StackSpec (str or mapping)
    algorithm: str
    budget: int
    actors: int
    objective: str
    seed: int
    reruns: int
    plan_timeout: float
    parameters: Mapping[str, Any] = field(default_factory=dict)
    loop: str = "open"  # open (the paper's) or closed (the ego drives the stack's plans)
    reactive_actors: bool = False  # closed loop: moving vehicles react to the ego
    bag_params: Mapping[str, Any] | None = None  # the bag's layout (bag_layout_json); None: the contract's

    def as_json(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.__dataclass_fields__}

    @staticmethod
    def from_json(values: Mapping[str, Any]) -> AttackPlan:
        return AttackPlan(**values)

    def options(self, out_dir: Path, config_dir: Path) -> AttackOptions:
        """The attack's options (the objective preset goes to the scorer's parameters)."""
        overrides = json.loads(json.dumps(self.parameters))
        scorer = overrides.setdefault(graph.SCORER.name, {})
        scorer.setdefault("objective", {})["preset"] = self.objective
        return AttackOptions(
            bag=Path(self.bag), out_dir=out_dir, stack=stack_spec(self.stack_entry, config_dir),
            algorithm=self.algorithm, queries=self.budget, actors=self.actors, seed=self.seed,
            window_start_frame=self.window_start, plan_timeout=self.plan_timeout, reruns=self.reruns,
            parameter_overrides=overrides, visual_report=False, loop=self.loop, reactive_actors=self.reactive_actors,
            bag_config=bag_layout_of(self.bag_params, f"attack {self.key} bag_params"),
        )  # fmt: skip


@dataclass(frozen=True)
class Campaign:
    """A checked campaign configuration."""

    path: Path
    digest: str  # of the configuration's text: a campaign folder belongs to one configuration
    scenarios: tuple[ScenarioSource, ...]
    stacks: Mapping[str, Any]  # campaign name -> config entry
    algorithms: Mapping[str, int]
    actors: tuple[int, ...]
    objectives: tuple[str, ...]
    seeds: tuple[int, ...]
    loops: tuple[str, ...]
    reactive_actors: bool  # for the closed-loop attacks
    reruns: int
    transfer: bool
    failure: FailureRule
    parameters: Mapping[str, Any]
    plan_timeout: float


def _fail(path: Path, key: str, problem: str) -> CampaignError:
    return CampaignError(f"{path}: {key}: {problem}")


def _unknown(path: Path, where: str, values: Mapping[str, Any], known: Sequence[str]) -> None:
    for key in values:
        if key not in known:
            raise _fail(path, f"{where}{key}", f"unknown key (known: {', '.join(known)})")


def _int_list(path: Path, key: str, value: Any, minimum: int) -> tuple[int, ...]:
    items = value if isinstance(value, list) else [value]
    if not items or not all(isinstance(v, int) and not isinstance(v, bool) and v >= minimum for v in items):
        raise _fail(path, key, f"expected an integer >= {minimum} or a list of them, got {value!r}")
    return tuple(items)


def stack_spec(entry: Any, config_dir: Path) -> StackSpec:
    """The StackSpec of a `stacks` entry: "reference", "learned", or {name, command, remap, remap_mode}."""
    if isinstance(entry, str):
        return StackSpec.parse(entry)
    spec = StackSpec.parse(str(entry["command"]), dict(entry.get("remap") or {}))
    params = tuple((config_dir / p).resolve() for p in entry.get("params") or ())
    return StackSpec(
        str(entry["name"]), spec.command, spec.remappings, str(entry.get("remap_mode", "relay")), params,
        sim_time=spec.sim_time,
    )  # fmt: skip


def _stacks(path: Path, value: Any) -> dict[str, Any]:
    if not isinstance(value, list) or not value:
        raise _fail(path, "stacks", "expected a non-empty list (reference, learned, or {name, command, remap})")
    stacks: dict[str, Any] = {}
    for index, entry in enumerate(value):
        where = f"stacks[{index}]"
        if isinstance(entry, str):
            if entry not in ("reference", "learned"):
                raise _fail(path, where, f"{entry!r}: not a reference stack (reference, learned); give a mapping "
                            "{name, command} for your own")  # fmt: skip
            name = entry
        elif isinstance(entry, dict):
            _unknown(path, f"{where}.", entry, STACK_KEYS)
            if not isinstance(entry.get("name"), str) or not isinstance(entry.get("command"), str):
                raise _fail(path, where, "a stack of your own needs a name and a command (strings)")
            name = entry["name"]
        else:
            raise _fail(path, where, f"expected a stack name or a mapping, got {entry!r}")
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name) or name in stacks:
            raise _fail(path, where, f"stack name {name!r} is not a unique name of letters, digits, _ . -")
        try:
            check_stack_command(stack_spec(entry, path.parent))
        except ScenarioError as error:
            raise _fail(path, where, str(error)) from None
        stacks[name] = entry
    return stacks


def _algorithms(path: Path, value: Any) -> dict[str, int]:
    if not isinstance(value, dict) or not value:
        raise _fail(path, "algorithms", "expected a mapping of algorithm to query budget, e.g. {bo: 75}")
    algorithms: dict[str, int] = {}
    for name, budget in value.items():
        known = accept_algorithm(name) if isinstance(name, str) else name  # an old name: a warning, its name now
        if known not in ALGORITHM_NAMES:
            raise _fail(path, f"algorithms.{name}", f"unknown algorithm (known: {', '.join(ALGORITHM_NAMES)})")
        if known in algorithms:
            raise _fail(path, f"algorithms.{name}", f"the same algorithm as {known!r}, named twice")
        if not isinstance(budget, int) or isinstance(budget, bool) or budget < 1:
            raise _fail(path, f"algorithms.{name}", f"the query budget must be a positive integer, got {budget!r}")
        algorithms[str(known)] = int(budget)
    return algorithms


def _bag_folder(path: Path, key: str, bag: Path) -> Path:
    if not (bag / "metadata.yaml").is_file():
        raise _fail(path, key, f"{bag} is not a rosbag2 folder (no metadata.yaml)")
    return bag.resolve()


def _windows(path: Path, key: str, value: Any) -> Any:
    if value in ("curated", "all"):
        return value
    if isinstance(value, dict) and len(value) == 1:
        ((kind, arg),) = value.items()
        if kind == "curated" and isinstance(arg, int) and not isinstance(arg, bool) and arg >= 1:
            return {"curated": arg}
        if kind == "starts":
            return {"starts": list(_int_list(path, f"{key}.starts", arg, 0))}
    raise _fail(path, key, f"expected curated, all, {{curated: K}} or {{starts: [FRAME, ...]}}, got {value!r}")


def _synthetic_sources(path: Path, where: str, synthetic: Any, windows: Any) -> list[ScenarioSource]:
    """``synthetic: {seeds: [...] | seed_range: [FIRST, END], families: [...]}``: one log per family and seed."""
    from advsim_ros.io.synthetic_families import FAMILY_NAMES

    if not isinstance(synthetic, dict) or len([k for k in ("seeds", "seed_range") if k in synthetic]) != 1:
        raise _fail(path, f"{where}.synthetic", "expected {seeds: [...]} or {seed_range: [FIRST, END]}")
    _unknown(path, f"{where}.synthetic.", synthetic, SYNTHETIC_KEYS)
    if "seeds" in synthetic:
        seeds = _int_list(path, f"{where}.synthetic.seeds", synthetic["seeds"], 0)
    else:
        first, end = _int_list(path, f"{where}.synthetic.seed_range", synthetic["seed_range"], 0)[:2]
        seeds = tuple(range(first, end))
    families = synthetic.get("families", ["street"])
    if not isinstance(families, list) or not families:
        raise _fail(path, f"{where}.synthetic.families", f"expected a list of scene families, got {families!r}")
    for family in families:
        if family not in FAMILY_NAMES:
            choices = ", ".join(FAMILY_NAMES)
            raise _fail(path, f"{where}.synthetic.families", f"unknown family {family!r} (one of {choices})")
    return [ScenarioSource(synthetic_source_name(f, s), Path(), windows, s, f) for f in families for s in seeds]


def synthetic_source_name(family: str, seed: int) -> str:
    """A synthetic log's name in a campaign (its scenario column): synthetic_seedN, synthetic_FAMILY_seedN."""
    return f"synthetic_seed{seed}" if family == "street" else f"synthetic_{family}_seed{seed}"


def scene_family(name: str) -> str:
    """The scene family of a campaign's scenario name (synthetic_source_name); other logs are their own family."""
    from advsim_ros.io.synthetic_families import FAMILY_NAMES

    found = re.fullmatch(r"synthetic_(?:([a-z_]+)_)?seed\d+", name)
    if found is None or (found.group(1) is not None and found.group(1) not in FAMILY_NAMES):
        return name
    return found.group(1) or "street"


def _bag_layout(path: Path, where: str, entry: Mapping[str, Any], default: BagConfig | None) -> BagConfig | None:
    """A bag | bags entry's layout: its own ``bag_params`` file (relative to the config), else --bag-params."""
    if "bag_params" not in entry:
        return default
    if "synthetic" in entry:
        raise _fail(path, f"{where}.bag_params", "only for bag and bags (synthetic logs have the contract's layout)")
    try:
        return load_bag_config(path.parent / str(entry["bag_params"]))
    except ScenarioError as error:
        raise _fail(path, f"{where}.bag_params", str(error)) from None


def _scenarios(path: Path, value: Any, bag_config: BagConfig | None = None) -> tuple[ScenarioSource, ...]:
    if not isinstance(value, list) or not value:
        raise _fail(path, "scenarios", "expected a non-empty list of {bag | bags | synthetic, windows}")
    sources: list[ScenarioSource] = []
    for index, entry in enumerate(value):
        where = f"scenarios[{index}]"
        if not isinstance(entry, dict):
            raise _fail(path, where, f"expected a mapping, got {entry!r}")
        _unknown(path, f"{where}.", entry, SCENARIO_KEYS)
        kinds = [k for k in ("bag", "bags", "synthetic") if k in entry]
        if len(kinds) != 1:
            raise _fail(path, where, "needs exactly one of bag, bags, synthetic")
        windows = _windows(path, f"{where}.windows", entry.get("windows", "curated"))
        layout = _bag_layout(path, where, entry, bag_config)
        kind = kinds[0]
        if kind == "bag":
            bag = _bag_folder(path, f"{where}.bag", path.parent / str(entry["bag"]))
            sources.append(ScenarioSource(bag.name, bag, windows, bag_config=layout))
        elif kind == "bags":
            folder = path.parent / str(entry["bags"])
            if not folder.is_dir():
                raise _fail(path, f"{where}.bags", f"{folder} is not a folder")
            bags = sorted(p.resolve() for p in folder.iterdir() if (p / "metadata.yaml").is_file())
            if not bags:
                raise _fail(path, f"{where}.bags", f"{folder} holds no rosbag2 folder")
            sources.extend(ScenarioSource(bag.name, bag, windows, bag_config=layout) for bag in bags)
        else:
            sources.extend(_synthetic_sources(path, where, entry["synthetic"], windows))
    names = [source.name for source in sources]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise _fail(path, "scenarios", f"scenario {duplicates[0]} is named twice")
    return tuple(sources)


def _exclusions(path: Path, failure: Mapping[str, Any]) -> tuple[str, ...]:
    exclude = failure.get("exclude", list(EXCLUSIONS))
    if not isinstance(exclude, list) or any(reason not in EXCLUSIONS for reason in exclude):
        raise _fail(path, "failure.exclude", f"expected a list of {', '.join(EXCLUSIONS)}, got {exclude!r}")
    return tuple(exclude)


def load_campaign(path: Path, bag_config: BagConfig | None = None) -> Campaign:
    """Read and check a campaign YAML (CampaignError naming the first problem); ``bag_config`` (--bag-params) is
    the layout of its bag | bags entries that name no bag_params of their own."""
    path = Path(path).resolve()
    try:
        text = path.read_text(encoding="utf-8")
        values = yaml.safe_load(text)
    except OSError as error:
        raise CampaignError(f"{path}: cannot read ({error.strerror})") from None
    except yaml.YAMLError as error:
        raise CampaignError(f"{path}: not valid YAML ({str(error).splitlines()[0]})") from None
    if not isinstance(values, dict):
        raise CampaignError(f"{path}: expected a mapping with scenarios, stacks, algorithms")
    _unknown(path, "", values, TOP_KEYS)
    for required in ("scenarios", "stacks", "algorithms"):
        if required not in values:
            raise _fail(path, required, "missing")
    objectives = values.get("objectives", ["M5"])
    objectives = objectives if isinstance(objectives, list) else [objectives]
    for name in objectives:
        if name not in PRESET_NAMES:
            raise _fail(path, "objectives", f"{name!r} is not one of {', '.join(PRESET_NAMES)}")
    failure = values.get("failure") or {}
    if not isinstance(failure, dict):
        expected = "expected {collision: true|false, adversarial_loss_above: VALUE|null, exclude: [...]}"
        raise _fail(path, "failure", expected)
    _unknown(path, "failure.", failure, FAILURE_KEYS)
    parameters = values.get("parameters") or {}
    if not isinstance(parameters, dict) or not all(isinstance(v, dict) for v in parameters.values()):
        raise _fail(path, "parameters", "expected {node: {parameter: value}}")
    loops = values.get("loops", ["open"])
    loops = loops if isinstance(loops, list) else [loops]
    if not loops or any(loop not in ("open", "closed") for loop in loops) or len(set(loops)) != len(loops):
        raise _fail(path, "loops", f"expected open, closed or both, got {values.get('loops')!r}")
    reactive_actors = values.get("reactive_actors", False)
    if not isinstance(reactive_actors, bool):
        raise _fail(path, "reactive_actors", f"expected true or false, got {reactive_actors!r}")
    if reactive_actors and "closed" not in loops:
        raise _fail(path, "reactive_actors", "only for closed-loop attacks: add closed to loops")
    reruns = _int_list(path, "reruns", values.get("reruns", 1), 0)
    plan_timeout = values.get("plan_timeout", 10.0)
    if not isinstance(plan_timeout, (int, float)) or not math.isfinite(plan_timeout) or plan_timeout <= 0:
        raise _fail(path, "plan_timeout", f"expected a positive number of seconds, got {plan_timeout!r}")
    layout = json.dumps(bag_layout_json(bag_config)) if bag_config else ""  # counts; without it: as before
    return Campaign(
        path=path,
        digest=hashlib.sha256((text + layout).encode()).hexdigest()[:16],
        scenarios=_scenarios(path, values["scenarios"], bag_config),
        stacks=_stacks(path, values["stacks"]),
        algorithms=_algorithms(path, values["algorithms"]),
        actors=_int_list(path, "actors", values.get("actors", [1]), 1),
        objectives=tuple(str(o) for o in objectives),
        seeds=_int_list(path, "seeds", values.get("seeds", [0]), 0),
        loops=tuple(str(loop) for loop in loops),
        reactive_actors=reactive_actors,
        reruns=reruns[0],
        transfer=bool(values.get("transfer", True)),
        failure=FailureRule(
            bool(failure.get("collision", True)), failure.get("adversarial_loss_above"), _exclusions(path, failure)
        ),
        parameters=parameters,
        plan_timeout=float(plan_timeout),
    )


def materialize(campaign: Campaign, logs_dir: Path) -> Campaign:
    """The campaign with its synthetic logs written under logs_dir (kept when already there)."""
    from advsim_ros.io.synthetic import SyntheticConfig, write_synthetic_bag

    sources = []
    for source in campaign.scenarios:
        if source.synthetic_seed is not None:
            bag = logs_dir / source.name
            if not (bag / "metadata.yaml").is_file():
                config = SyntheticConfig(family=source.synthetic_family)
                write_synthetic_bag(bag, seed=source.synthetic_seed, config=config)
            source = replace(source, bag=bag.resolve())
        sources.append(source)
    return Campaign(**{**campaign.__dict__, "scenarios": tuple(sources)})


def window_starts(campaign: Campaign, source: ScenarioSource, params_dir: Path | None = None) -> list[int]:
    """The first frames of the windows to attack in one log (checked against the log's length)."""
    params = params_dir or default_params_dir()
    scenario = read_scenario_bag(source.bag, config=source.bag_config, load_sweeps=False)
    where = f"scenarios[{source.name}].windows"
    if isinstance(source.windows, dict) and "starts" in source.windows:
        for start in source.windows["starts"]:
            try:
                WindowConfig(window_start_frame=start).frame_indices(scenario.num_frames)
            except ScenarioError as error:
                raise _fail(campaign.path, where, str(error)) from None
        return list(source.windows["starts"])
    curation_file = params / "curation.yaml"
    config = load_curation_config(curation_file) if curation_file.exists() else CurationConfig()
    try:
        candidates = curate_windows(scenario, config)
    except ScenarioError as error:
        raise _fail(campaign.path, where, str(error)) from None
    if source.windows == "all":
        return [w.start_frame for w in candidates]
    count = 1 if source.windows == "curated" else int(source.windows["curated"])
    ranked = sorted(candidates, key=lambda w: (-w.collision_rate, w.start_frame))
    return sorted(w.start_frame for w in ranked[:count])


def expand(campaign: Campaign, params_dir: Path | None = None) -> list[AttackPlan]:
    """Every attack of the campaign, in a stable order (scenario, window, stack, algorithm, actors, objective, seed)."""
    plans: list[AttackPlan] = []
    for source in campaign.scenarios:
        for start in window_starts(campaign, source, params_dir):
            for stack, (algorithm, budget), actors, objective, seed, loop in itertools.product(
                campaign.stacks, campaign.algorithms.items(), campaign.actors, campaign.objectives, campaign.seeds,
                campaign.loops,
            ):  # fmt: skip
                key = f"{source.name}-w{start:04d}-{stack}-{algorithm}{budget}-m{actors}-{objective}-s{seed}"
                key += "-closed" if loop == "closed" else ""  # open-loop keys as before: their journals resume
                reactive = campaign.reactive_actors and loop == "closed"
                key += "-reactive" if reactive else ""
                plans.append(
                    AttackPlan(
                        key=re.sub(r"[^A-Za-z0-9_.-]", "_", key),
                        scenario=source.name,
                        bag=str(source.bag),
                        window_start=start,
                        stack=stack,
                        stack_entry=campaign.stacks[stack],
                        algorithm=algorithm,
                        budget=budget,
                        actors=actors,
                        objective=objective,
                        seed=seed,
                        reruns=campaign.reruns,
                        plan_timeout=campaign.plan_timeout,
                        parameters=campaign.parameters,
                        loop=loop,
                        reactive_actors=reactive,
                        bag_params=bag_layout_json(source.bag_config),
                    )
                )
    return plans
