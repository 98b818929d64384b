"""Reusable field components: MLPs, positional encoding and multi-resolution dense grids.

The grids are pure PyTorch (``grid_sample``), so the same code runs on CPU, CUDA and MPS; they replace
the paper's big positional-encoded MLPs where capacity per CPU-second matters (atlas colours, alpha).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


class MLP(nn.Module):
    """ReLU MLP; ``skips`` feed the (encoded) input again to those layer indices (paper: atlas 4 and 7)."""

    def __init__(
        self,
        d_in: int,
        d_out: int,
        hidden: int,
        layers: int,
        skips: tuple[int, ...] = (),
        zero_last: bool = False,
    ) -> None:
        super().__init__()
        self.skips = tuple(skips)
        self.linears = nn.ModuleList()
        for i in range(layers):
            d = d_in if i == 0 else hidden + (d_in if i in self.skips else 0)
            self.linears.append(nn.Linear(d, d_out if i == layers - 1 else hidden))
        if zero_last:
            nn.init.zeros_(self.linears[-1].weight)
            nn.init.zeros_(self.linears[-1].bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        inp = x
        for i, lin in enumerate(self.linears):
            if i > 0:
                x = F.relu(x)
            if i in self.skips:
                x = torch.cat((x, inp), dim=-1)
            x = lin(x)
        return x


class PositionalEncoding(nn.Module):
    """sin/cos at frequencies 2^k * pi, k < n (the paper's encoding, without the raw input)."""

    def __init__(self, n_freq: int) -> None:
        super().__init__()
        self.register_buffer("freqs", (2.0 ** torch.arange(n_freq)) * math.pi, persistent=False)

    def out_dim(self, d_in: int) -> int:
        return 2 * d_in * len(self.freqs)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        proj = x[..., :, None] * self.freqs  # [N, d, n]
        return torch.cat((torch.sin(proj), torch.cos(proj)), dim=-2).flatten(-2)


def level_resolutions(finest: int, levels: int, coarsest: int = 16) -> list[int]:
    """Geometric ladder of grid resolutions from ``coarsest`` (or finest if smaller) to ``finest``."""
    finest = max(2, int(finest))
    coarsest = max(2, min(coarsest, finest))
    if levels <= 1:
        return [finest]
    g = (finest / coarsest) ** (1.0 / (levels - 1))
    return sorted({max(2, round(coarsest * g**i)) for i in range(levels)})


class Grid2D(nn.Module):
    """Multi-resolution dense 2D feature grids over [-1, 1]^2, bilinearly interpolated and concatenated."""

    def __init__(self, resolutions: list[tuple[int, int]], features: int, init_std: float = 1e-2) -> None:
        super().__init__()
        self.grids = nn.ParameterList(
            [nn.Parameter(torch.randn(1, features, h, w) * init_std) for (w, h) in resolutions]
        )
        self.out_dim = features * len(resolutions)

    def forward(self, uv: torch.Tensor) -> torch.Tensor:
        g = uv.view(1, 1, -1, 2).to(self.grids[0].dtype)
        feats = [
            F.grid_sample(grid, g, mode="bilinear", padding_mode="border", align_corners=True)[0, :, 0].t()
            for grid in self.grids
        ]
        return torch.cat(feats, dim=-1)


class Grid3D(nn.Module):
    """Multi-resolution dense 3D feature grids over [-1, 1]^3 (x, y, t), trilinearly interpolated."""

    def __init__(self, resolutions: list[tuple[int, int, int]], features: int, init_std: float = 1e-2) -> None:
        super().__init__()
        self.grids = nn.ParameterList(
            [nn.Parameter(torch.randn(1, features, d, h, w) * init_std) for (w, h, d) in resolutions]
        )
        self.out_dim = features * len(resolutions)

    def forward(self, xyt: torch.Tensor) -> torch.Tensor:
        g = xyt.view(1, 1, 1, -1, 3).to(self.grids[0].dtype)
        feats = [
            F.grid_sample(grid, g, mode="bilinear", padding_mode="border", align_corners=True)[0, :, 0, 0].t()
            for grid in self.grids
        ]
        return torch.cat(feats, dim=-1)
