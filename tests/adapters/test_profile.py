"""Stack profiles: the shipped ones load, defaults fit the contract, and every mistake is one line naming it."""

from __future__ import annotations

from pathlib import Path

import pytest

from advsim_ros.adapters.profile import ProfileError, StackProfile, load_profile

PROFILES = Path(__file__).resolve().parents[2] / "params" / "stacks"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "profile.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("name", ["modular", "learned", "example", "autoware"])
def test_every_shipped_profile_loads(name: str) -> None:
    profile = load_profile(PROFILES / f"{name}.yaml")
    assert profile.processes
    assert all(path.is_file() for process in profile.processes for path in profile.params_paths(process))


def test_the_reference_profiles_speak_the_contract_so_nothing_is_adapted() -> None:
    for name in ("modular", "learned", "example"):
        profile = load_profile(PROFILES / f"{name}.yaml")
        assert not profile.adapted(), name


def test_the_autoware_profile_renames_and_converts() -> None:
    profile = load_profile(PROFILES / "autoware.yaml")
    assert profile.renamed() == {
        "/sensor/lidar/points": "/sensing/lidar/concatenated/pointcloud",
        "/ego/odom": "/localization/kinematic_state",
        "/planning/trajectory": "/planning/scenario_planning/trajectory",
        "/perception/detections": "/perception/object_recognition/detection/objects",
        "/prediction/tracks": "/perception/object_recognition/objects",
    }
    assert profile.converts()
    assert profile.timing.timer
    assert profile.outputs.plan.type == "autoware_trajectory"


def test_a_minimal_profile_gets_the_contract_defaults(tmp_path: Path) -> None:
    profile = load_profile(_write(tmp_path, "processes: [{command: my_stack --fast}]\n"))
    assert profile.processes[0].argv == ("my_stack", "--fast")
    assert profile.timing.mode == "per_sweep"
    assert profile.inputs.pose.type == "odometry"
    assert profile.renamed() == {}
    assert not profile.adapted()


def test_commands_expand_environment_variables_and_advsims_interpreter(tmp_path: Path) -> None:
    import sys

    profile = load_profile(_write(tmp_path, 'processes: [{command: "$ADVSIM_PYTHON -m pkg ${HOME}"}]\n'))
    argv = profile.processes[0].argv
    assert argv[0] == sys.executable
    assert argv[1:3] == ("-m", "pkg")
    assert "$" not in argv[3]


def test_cwd_is_relative_to_the_profile_and_env_expands_like_the_command(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "stack" / "bin").mkdir(parents=True)
    monkeypatch.setenv("MY_LIBS", "/opt/libs")
    text = "processes: [{command: ./run, cwd: stack/bin, env: {PYTHONPATH: '${MY_LIBS}:x', MODE: fast}}]\n"
    profile = load_profile(_write(tmp_path, text))
    process = profile.processes[0]
    assert profile.cwd_path(process) == (tmp_path / "stack" / "bin").resolve()
    assert process.environment == {"PYTHONPATH": "/opt/libs:x", "MODE": "fast"}
    assert process.env["PYTHONPATH"] == "${MY_LIBS}:x"  # the file's text; expanded when the process starts
    assert profile.cwd_path(load_profile(_write(tmp_path, "processes: [{command: a}]\n")).processes[0]) is None


def test_the_profile_round_trips_through_json(tmp_path: Path) -> None:
    profile = load_profile(PROFILES / "autoware.yaml")
    copy = tmp_path / "copy.json"
    copy.write_text(profile.to_json())
    assert load_profile(copy) == profile


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("processes: []\n", "processes: at least one command"),
        ("processes: [{command: a}]\nplanner: x\n", "unknown parameter(s) ['planner']"),
        ("processes: [{command: a}]\noutputs: {plan: {type: trajectory}}\n", "type 'trajectory': one of path"),
        ("processes: [{command: a}]\ninputs: {pose: {type: navsatfix, topic: /fix}}\n", "navsatfix needs a datum"),
        (
            "processes: [{command: a}]\noutputs: {plan: {frame_origin: first_fix, frame_id: map}}\n",
            "needs inputs.pose.type navsatfix",
        ),
        ("processes: [{command: a}]\noutputs: {plan: {frame_origin: static}}\n", "needs the frame's name in frame_id"),
        ("processes: [{command: a}]\ninputs: {lidar: {topic: points}}\n", "'points' is not an absolute topic name"),
        ("processes: [{command: a}]\ntiming: {mode: timer, clock_step: 0.0}\n", "clock_step: must be positive"),
        ("processes: [{command: a}]\ntiming: {mode: async}\n", "mode 'async': one of per_sweep, timer"),
        ("processes: [{command: a}]\ninputs: {topics: {/planning/trajectory: /x}}\n", "is not one of"),
        ("profile: 2\nprocesses: [{command: a}]\n", "reads schema 1, got 2"),
        ("processes: [{command: a}, {command: b}]\n", "names must differ"),
        ("processes: [{command: a, params_files: [nowhere.yaml]}]\n", "nowhere.yaml of stack does not exist"),
        ("processes: [{command: a, ros_args: false, parameters: {x: 1}}]\n", "need ros_args: true"),
        ("processes: [{command: a}]\ninputs: {pose: {datum: {latitude: 95, longitude: 0}}}\n", "out of range"),
        ("processes: [{command: a}]\ninputs: {lidar: {also: [/sensor/lidar/points]}}\n", "must differ"),
        ("processes: [{command: a}]\ninputs: {lidar: {frame_id: velodyne}}\n", "give topic"),
        ("processes: [{command: a}]\noutputs: {plan: {type: spatial_path}}\n", "name yours"),
        (
            "processes: [{command: a}]\noutputs: {detections: {type: marker_array, topic: /perception/detections}}\n",
            "name yours",
        ),
        ("processes: [{command: a}]\noutputs: {detections: {type: boxes, topic: /d}}\n", "detections.type 'boxes'"),
        ("processes: [{command: a}]\noutputs: {plan: {reliability: fast, topic: /p}}\n", "reliability 'fast'"),
        ("processes: [{command: a}]\noutputs: {plan: {reliability: best_effort}}\n", "name yours"),
        ("processes: [{command: a}]\noutputs: {plan: {headings: zero, topic: /p}}\n", "headings 'zero': one of auto"),
        ("processes: [{command: a}]\noutputs: {plan: {headings: tangent}}\n", "name yours"),  # converted
        ("- a\n", "expected a mapping"),
        ("processes: [{command: 'a}]\n", "not valid YAML"),
        ("processes: [{command: a, cwd: nowhere}]\n", "nowhere of stack is not a folder"),
        ("processes: [{command: a, env: {THREADS: 4}}]\n", "env.THREADS: expected a string, got 4"),
        ("processes: [{command: a, env: {'A B': x}}]\n", "'A B' is not an environment variable's name"),
        ("processes: [{command: a, env: [A=1]}]\n", "env: expected a mapping"),
    ],
)
def test_a_bad_profile_is_refused_with_one_line_naming_the_problem(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ProfileError) as error:
        load_profile(_write(tmp_path, text))
    assert message in str(error.value)
    assert "\n" not in str(error.value)
    assert str(tmp_path / "profile.yaml") in str(error.value)


def test_a_missing_profile_file_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(ProfileError, match="cannot read it"):
        load_profile(tmp_path / "absent.yaml")


def test_profiles_are_frozen_values() -> None:
    profile = load_profile(PROFILES / "example.yaml")
    assert isinstance(profile, StackProfile)
    with pytest.raises(AttributeError):
        profile.name = "other"  # type: ignore[misc]
