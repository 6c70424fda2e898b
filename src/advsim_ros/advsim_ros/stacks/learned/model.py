"""The imitation-learning planner network (torch, CPU).

Stride-2 convolutions turn the BEV raster into a coarse feature map, a 1x1 convolution
narrows it and it is flattened (where things are matters to a planner, so no global
pooling); with the ego's motion features it goes through an MLP. Its outputs are the
coefficients of a smooth correction to the motion prior (the ego keeping its speed and
yaw rate): Bernstein polynomials over the horizon that start with zero offset and zero
slope, so a plan leaves the ego's current state smoothly and its accelerations and jerk
stay bounded, whatever the network says.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from advsim_ros.stacks.learned.config import ModelConfig, RasterConfig
from advsim_ros.stacks.learned.raster import NUM_MOTION_FEATURES


def num_features(raster: RasterConfig) -> int:
    return NUM_MOTION_FEATURES + 2 * raster.history


def correction_basis(num_steps: int, degree: int) -> torch.Tensor:
    """(num_steps, degree - 1) Bernstein polynomials b_2..b_degree of time over the horizon.

    They and their slopes are zero at time 0: the correction leaves the ego's current state untouched.
    """
    fraction = torch.arange(1, num_steps + 1, dtype=torch.float64) / num_steps
    columns = [math.comb(degree, k) * fraction**k * (1.0 - fraction) ** (degree - k) for k in range(2, degree + 1)]
    return torch.stack(columns, dim=1).float()


class BevPlanner(nn.Module):
    """Raster (B, C, H, W) + motion features (B, F) + prior (B, T, 2) -> waypoints (B, T, 2) in the ego frame [m]."""

    def __init__(self, raster: RasterConfig, model: ModelConfig, num_steps: int) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        channels_in = raster.num_channels
        for channels_out in model.channels:
            layers += [nn.Conv2d(channels_in, channels_out, 3, stride=2, padding=1), nn.ReLU()]
            channels_in = channels_out
        layers += [nn.Conv2d(channels_in, model.bottleneck, 1), nn.ReLU()]
        self.encoder = nn.Sequential(*layers)
        rows, columns = raster.shape
        for _ in model.channels:
            rows, columns = (rows + 1) // 2, (columns + 1) // 2
        flat = model.bottleneck * rows * columns
        self.head = nn.Sequential(
            nn.Linear(flat + num_features(raster), model.hidden),
            nn.ReLU(),
            nn.Linear(model.hidden, model.hidden),
            nn.ReLU(),
            nn.Linear(model.hidden, 2 * (model.basis_degree - 1)),
        )
        self.basis: torch.Tensor
        self.register_buffer("basis", correction_basis(num_steps, model.basis_degree))
        self.num_steps = num_steps
        self.residual_scale = model.residual_scale

    def forward(self, image: torch.Tensor, features: torch.Tensor, prior: torch.Tensor) -> torch.Tensor:
        encoded = self.encoder(image).flatten(start_dim=1)
        coefficients = self.head(torch.cat([encoded, features], dim=1)).view(-1, 2, self.basis.shape[1])
        correction = torch.einsum("bdk,tk->btd", coefficients, self.basis)
        return prior + self.residual_scale * correction
