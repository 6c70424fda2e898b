"""Parameters of the learned stack (params/stack_learned.yaml, node /learned_stack)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

from advsim_ros.core.types import ScenarioError
from advsim_ros.io.synthetic_families import FAMILY_NAMES
from advsim_ros.stacks.interface import TopicIoConfig
from advsim_ros.stacks.modular.config import GroundConfig
from advsim_ros.stacks.params import default_params_file, load_stack_config

NODE_NAME = "learned_stack"
PACKAGED_WEIGHTS = Path(__file__).resolve().parent / "weights" / "il_planner.pt"


def _check_range(name: str, bounds: tuple[float, ...]) -> None:
    if len(bounds) != 2 or not all(math.isfinite(value) for value in bounds) or not bounds[0] < bounds[1]:
        raise ScenarioError(f"raster {name}: expected [low, high] with low < high, got {list(bounds)}")


@dataclass(frozen=True)
class RasterConfig:
    """Bird's-eye-view raster of the last second of LiDAR, in the current ego frame (x forward, y left)."""

    x_range: tuple[float, ...] = (-20.0, 60.0)  # raster extent along x [m]
    y_range: tuple[float, ...] = (-32.0, 32.0)  # raster extent along y [m]
    resolution: float = 1.0  # cell edge [m]
    history: int = 10  # sweeps in the raster (1 s at 10 Hz), newest first
    band_edges: tuple[float, ...] = (0.25, 1.0, 2.5)  # heights above the ground splitting the object bands [m]
    dedupe_cell: float = 0.25  # returns sharing a cell this size (and band) are kept once [m]
    max_gap_s: float = 0.5  # a jump in time longer than this (or backwards) forgets the history [s]

    def __post_init__(self) -> None:
        _check_range("x_range", self.x_range)
        _check_range("y_range", self.y_range)
        if not (math.isfinite(self.resolution) and self.resolution > 0):
            raise ScenarioError(f"raster resolution: must be positive, got {self.resolution}")
        if self.history < 1:
            raise ScenarioError(f"raster history: must be >= 1, got {self.history}")
        edges = self.band_edges
        if len(edges) < 2 or any(b <= a for a, b in itertools.pairwise(edges)):
            raise ScenarioError(f"raster band_edges: need >= 2 increasing heights, got {list(edges)}")
        if not (self.dedupe_cell > 0 and self.max_gap_s > 0):
            raise ScenarioError("raster dedupe_cell, max_gap_s: must be positive")

    @property
    def shape(self) -> tuple[int, int]:
        """(rows along y, columns along x) of one channel."""
        rows = round((self.y_range[1] - self.y_range[0]) / self.resolution)
        columns = round((self.x_range[1] - self.x_range[0]) / self.resolution)
        return rows, columns

    @property
    def num_bands(self) -> int:
        return len(self.band_edges) - 1

    @property
    def num_channels(self) -> int:
        """Object bands of every history sweep, plus the newest sweep's ground returns."""
        return self.history * self.num_bands + 1


@dataclass(frozen=True)
class ModelConfig:
    """The convolutional planner: strided convolutions over the raster, an MLP with the ego's motion."""

    channels: tuple[int, ...] = (16, 32, 64)  # output channels of the stride-2 convolutions
    bottleneck: int = 8  # 1x1 convolution width before flattening
    hidden: int = 128  # width of the fully connected layer
    residual_scale: float = 5.0  # network outputs are scaled by this to metres on top of the motion prior [m]
    basis_degree: int = 5  # degree of the smooth correction polynomials (degree - 1 coefficients per axis)

    def __post_init__(self) -> None:
        if not self.channels or min(self.channels) < 1 or self.bottleneck < 1 or self.hidden < 1:
            raise ScenarioError("model channels, bottleneck, hidden: must be positive")
        if not self.residual_scale > 0:
            raise ScenarioError(f"model residual_scale: must be positive, got {self.residual_scale}")
        if self.basis_degree < 2:
            raise ScenarioError(f"model basis_degree: must be >= 2, got {self.basis_degree}")


@dataclass(frozen=True)
class TrainingConfig:
    """Imitation learning on the project's own data; the same config and seed give the same weights."""

    seed: int = 0  # seeds every random draw (torch and numpy) of data generation and training
    epochs: int = 30  # passes over the training samples
    batch_size: int = 16  # samples per step (doubled by mirroring)
    learning_rate: float = 1.0e-3  # Adam step size
    weight_decay: float = 1.0e-4  # Adam L2 penalty
    kitti_sequence: str = "0000"  # KITTI tracking sequence used (from the data folder given to the command)
    kitti_last_decision: int = 59  # KITTI decision frames up to this one train; later ones are held out
    synthetic_seeds: tuple[int, ...] = (100, 101, 102, 103)  # synthetic logs generated for training
    synthetic_duration: float = 10.0  # length of each synthetic training log [s]
    # scene families (io.synthetic_families) of the training seeds that standard training reads; the packaged
    # weights read street logs only, Table 2's standard stack (scripts/table2.sh) also the interaction families
    families: tuple[str, ...] = ("street",)
    mirror: bool = True  # add every sample mirrored left-right
    threads: int = 2  # torch intra-op threads (fixed, so that sums are reduced in the same order)
    validation_seeds: tuple[int, ...] = (104, 105)  # synthetic logs that validate fine-tuning (never trained on)
    finetune_epochs: int = 10  # curriculum / robust: most passes when fine-tuning on logs + extra samples
    finetune_learning_rate: float = 3.0e-4  # curriculum / robust: Adam step size when fine-tuning
    finetune_repeat: int = 5  # curriculum / robust: each hard window or found scenario counts this many times
    finetune_patience: int = 3  # fine-tuning stops after this many passes without a better validation loss
    curriculum_fraction: float = 0.25  # curriculum: the hardest fraction of train windows (by curation rate)
    # curriculum / robust: scene families (io.synthetic_families) of the training seeds whose windows curriculum
    # ranks, and of the validation seeds that early stopping measures; standard training reads street logs only.
    # Not left_turn: the stack has no route input, so nothing it sees says whether the human turns or goes on
    finetune_families: tuple[str, ...] = ("street", "lead_brake", "cut_in", "crossing")

    def __post_init__(self) -> None:
        counts = (self.epochs, self.batch_size, self.threads, self.finetune_epochs, self.finetune_repeat,
                  self.finetune_patience)  # fmt: skip
        if min(counts) < 1:
            raise ScenarioError(
                "training epochs, batch_size, threads, finetune_epochs, finetune_repeat, finetune_patience: "
                "must be >= 1"
            )
        if not self.finetune_learning_rate > 0:
            raise ScenarioError("training finetune_learning_rate must be positive")
        if not 0.0 < self.curriculum_fraction <= 1.0:
            raise ScenarioError(f"training curriculum_fraction: must lie in (0, 1], got {self.curriculum_fraction}")
        if shared := sorted(set(self.synthetic_seeds) & set(self.validation_seeds)):
            raise ScenarioError(f"training validation_seeds: {shared} also train (synthetic_seeds)")
        if not (self.learning_rate > 0 and self.weight_decay >= 0):
            raise ScenarioError("training learning_rate must be positive and weight_decay >= 0")
        for key in ("families", "finetune_families"):
            if unknown := [family for family in getattr(self, key) if family not in FAMILY_NAMES]:
                expected = ", ".join(FAMILY_NAMES)
                raise ScenarioError(f"training {key}: unknown {unknown}; expected some of {expected}")
        if not self.families:
            raise ScenarioError("training families: name at least one scene family (street: the original logs)")
        if not 0.5 <= self.synthetic_duration <= 60.0:
            raise ScenarioError(f"training synthetic_duration: must lie in [0.5, 60] s, got {self.synthetic_duration}")


@dataclass(frozen=True)
class LearnedPlannerConfig:
    """The plan the learned stack publishes and the weights it runs."""

    horizon_s: float = 5.0  # plan length [s]
    step_s: float = 0.1  # time between plan poses [s]
    weights: str = ""  # weights file; "" = the packaged stacks/learned/weights/il_planner.pt
    threads: int = 1  # torch threads for inference (process-wide); one avoids contention on small CPUs

    def __post_init__(self) -> None:
        if not (self.horizon_s > 0 and self.step_s > 0 and self.horizon_s >= self.step_s):
            raise ScenarioError("planner horizon_s and step_s: need 0 < step_s <= horizon_s")
        if self.threads < 1:
            raise ScenarioError(f"planner threads: must be >= 1, got {self.threads}")


@dataclass(frozen=True)
class LearnedStackConfig:
    """The whole learned stack, one section per concern."""

    planner: LearnedPlannerConfig = field(default_factory=LearnedPlannerConfig)
    ground: GroundConfig = field(default_factory=GroundConfig)
    raster: RasterConfig = field(default_factory=RasterConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    training: TrainingConfig = field(default_factory=TrainingConfig)
    io: TopicIoConfig = field(default_factory=TopicIoConfig)

    @property
    def horizon_s(self) -> float:
        return self.planner.horizon_s

    @property
    def step_s(self) -> float:
        return self.planner.step_s

    @property
    def num_steps(self) -> int:
        return round(self.planner.horizon_s / self.planner.step_s)

    @property
    def weights_path(self) -> Path:
        return Path(self.planner.weights).expanduser() if self.planner.weights else PACKAGED_WEIGHTS


def load_learned_config(path: Path | None = None) -> LearnedStackConfig:
    """The learned stack's config from params/stack_learned.yaml (or `path`)."""
    return load_stack_config(LearnedStackConfig, path or default_params_file("stack_learned.yaml"), NODE_NAME)
