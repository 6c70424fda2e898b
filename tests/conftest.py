"""Fixtures shared by the test folders under tests/."""

from __future__ import annotations

import importlib.util
import resource
import shutil
import signal
import time
import traceback
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from advsim_ros.core.types import EgoTrajectory, Scenario
from advsim_ros.io.bag import BagConfig, write_scenario_bag

CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync", "--window-size=1200,2400",
)  # fmt: skip


@pytest.fixture
def chromium(tmp_path: Path) -> Iterator[Any]:
    """A real headless Chromium (Debian's chromium + chromedriver) driven by selenium, browser log kept.

    Skips only when chromium, chromedriver or selenium is absent (scripts/setup.sh installs them
    when it runs as root).
    """
    binary, driver_path = shutil.which("chromium"), shutil.which("chromedriver")
    if binary is None or driver_path is None or importlib.util.find_spec("selenium") is None:
        pytest.skip("Debian's chromium and chromium-driver are not installed (make setup installs them as root)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'chromium-profile'}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=options, service=Service(executable_path=driver_path))
    driver.set_page_load_timeout(60)
    try:
        yield driver
    finally:
        driver.quit()


_JAZZY = get_typestore(Stores.ROS2_JAZZY)
_POINT_DATATYPES = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}


class CloudBags:
    """Scenario bags whose LiDAR clouds are given as they are, any fields (even without z), any values:
    the clouds a driver records, which write_scenario_bag itself would refuse to write."""

    frame_period_ns = 100_000_000
    first_stamp_ns = 1_000_000_000

    def stamp(self, frame: int) -> int:
        return self.first_stamp_ns + self.frame_period_ns * frame

    @staticmethod
    def points(count: int, seed: int = 0) -> np.ndarray:
        """x, y, z float32, intensity uint8 and ring uint16 after a padding byte, time float64: 24-byte points."""
        dtype = np.dtype(
            {
                "names": ["x", "y", "z", "intensity", "ring", "time"],
                "formats": ["<f4", "<f4", "<f4", "u1", "<u2", "<f8"],
                "offsets": [0, 4, 8, 12, 14, 16],
                "itemsize": 24,
            }
        )
        rng = np.random.default_rng(seed)
        raw = rng.integers(0, 256, count * dtype.itemsize, dtype=np.uint8)  # padding bytes random too
        points = raw.view(dtype).copy()
        for name in ("x", "y", "z"):
            points[name] = rng.uniform(-30.0, 30.0, count)
        points["time"] = np.linspace(0.0, 0.1, count)
        return points

    def cloud_cdr(self, points: np.ndarray, frame: int, height: int = 1) -> bytes:
        """A PointCloud2 (CDR) of these points as laid out, ``height`` rows (organised when > 1)."""
        names = points.dtype.names or ()
        fields = [
            _JAZZY.types["sensor_msgs/msg/PointField"](
                name=name,
                offset=points.dtype.fields[name][1],
                datatype=_POINT_DATATYPES[points.dtype[name].str[1:]],
                count=1,
            )
            for name in names
        ]
        stamp = self.stamp(frame)
        width = points.shape[0] // height if height else 0
        message = _JAZZY.types["sensor_msgs/msg/PointCloud2"](
            header=_JAZZY.types["std_msgs/msg/Header"](
                stamp=_JAZZY.types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9),
                frame_id="lidar",
            ),
            height=height,
            width=width,
            fields=fields,
            is_bigendian=False,
            point_step=points.dtype.itemsize,
            row_step=points.dtype.itemsize * width,
            data=np.ascontiguousarray(points).view(np.uint8).reshape(-1),
            is_dense=False,
        )
        return bytes(_JAZZY.serialize_cdr(message, "sensor_msgs/msg/PointCloud2"))

    def write(
        self,
        path: Path,
        clouds: Mapping[int, bytes],
        num_frames: int = 70,
        storage: str = "mcap",
        compress: bool = False,
    ) -> Path:
        """A scenario bag of ``num_frames`` frames (the ego drives along x at 5 m/s, no actors) whose
        /sensor/lidar/points holds ``clouds`` (frame index -> PointCloud2 CDR, from cloud_cdr)."""
        stamps = np.array([self.stamp(frame) for frame in range(num_frames)], dtype=np.int64)
        poses = np.tile(np.eye(4), (num_frames, 1, 1))
        poses[:, 0, 3] = 0.5 * np.arange(num_frames)
        mount = np.eye(4)
        mount[2, 3] = 1.8
        scenario = Scenario(
            scenario_id=path.name,
            frame_stamps_ns=stamps,
            ego=EgoTrajectory(stamps_ns=stamps, poses=poses),
            actors=(),
            ego_T_sensor=mount,
            sensor_frame="lidar",
        )
        lidar = BagConfig().lidar_topic
        # the scenario's own (empty) LiDAR topic goes elsewhere; the given clouds are the bag's LiDAR
        config = BagConfig(lidar_topic="/unused/points", storage=storage, compress=compress)
        extra = [(lidar, "sensor_msgs/msg/PointCloud2", self.stamp(frame), clouds[frame]) for frame in sorted(clouds)]
        return write_scenario_bag(scenario, path, config=config, extra=extra)


@pytest.fixture(scope="session")
def cloud_bags() -> CloudBags:
    """Writes scenario bags with clouds as drivers record them (see CloudBags)."""
    return CloudBags()


class CaseTimeout(BaseException):
    """A fuzz case ran past its time limit (a BaseException: no `except Exception` under test can hide it)."""


def _on_alarm(signum: int, frame: object) -> None:
    raise CaseTimeout


class FuzzCases:
    """Runs fuzz cases one by one: each must return (a correct read; the case asserts what that means) or raise
    one of ``clean`` with a one-line message, within ``limit_s``; anything else (another exception type, a
    multi-line message, a failed assertion, running past the limit) is a failure, named with its case."""

    def __init__(self, clean: tuple[type[BaseException], ...], limit_s: float) -> None:
        self.clean, self.limit_s = clean, limit_s
        self.count = self.errors = 0
        self.failures: list[str] = []
        self.slowest = 0.0
        self._peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

    def run(self, name: str, case: Callable[[], object]) -> None:
        self.count += 1
        previous = signal.signal(signal.SIGALRM, _on_alarm)
        outer, _ = signal.setitimer(signal.ITIMER_REAL, self.limit_s)  # pytest-timeout's alarm, if set
        started = time.perf_counter()
        try:
            case()
        except CaseTimeout:
            self.failures.append(f"{name}: ran past {self.limit_s} s")
        except self.clean as error:
            self.errors += 1
            if "\n" in str(error) or not str(error):
                self.failures.append(f"{name}: {type(error).__name__} without a one-line message: {error!r}")
        except Exception as error:  # any other exception is what the fuzz looks for
            where = traceback.extract_tb(error.__traceback__)[-1]
            self.failures.append(f"{name}: {type(error).__name__}: {error} ({where.filename}:{where.lineno})")
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
            spent = time.perf_counter() - started
            self.slowest = max(self.slowest, spent)
            if outer:  # pytest-timeout's alarm goes on with what is left of it
                signal.setitimer(signal.ITIMER_REAL, max(outer - spent, 0.001))

    def check(self, minimum: int, memory_mb: float) -> None:
        """At least ``minimum`` cases, no failure, and the process's peak memory grew by less than ``memory_mb``."""
        grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - self._peak_kb) / 1024
        print(
            f"fuzz: {self.count} cases, {self.errors} clean errors, {self.count - self.errors} reads, "
            f"slowest {self.slowest:.2f} s, peak memory +{grown_mb:.0f} MB"
        )
        assert self.failures == [], f"{len(self.failures)} of {self.count} cases failed:\n" + "\n".join(
            self.failures[:30]
        )
        assert self.count >= minimum
        assert grown_mb < memory_mb


@pytest.fixture
def fuzz_cases() -> Callable[[tuple[type[BaseException], ...], float], FuzzCases]:
    """Makes a FuzzCases runner: fuzz_cases((clean error types), per-case limit [s])."""
    return FuzzCases
