"""The paper's architecture, exactly: the faithful baseline the fast model is measured against.

Foreground mapping 6x256, background mapping 4x256 (no positional encoding, tanh output); one atlas MLP
8x256 with positional encoding N=10 and skips to layers 4 and 7, the background in the quadrant
[-1,0]^2 and the foreground in [0,1]^2; alpha MLP 8x256 with positional encoding N=5. Mappings are
calibrated to ``uv_mapping_scale`` * identity before training.
"""

from __future__ import annotations

import torch

from ..config import FitConfig
from .atlas_model import ALPHA_FLOOR, ALPHA_SPAN, AtlasModel
from .fields import MLP, PositionalEncoding

HIDDEN = 256
#: Linear layers of the background and foreground mappings, the atlas and the alpha MLPs (each HIDDEN wide).
BG_MAPPING_LAYERS, FG_MAPPING_LAYERS, ATLAS_LAYERS, ALPHA_LAYERS = 4, 6, 8, 8
#: The atlas MLP feeds its encoded input again to these layers.
ATLAS_SKIPS = (4, 7)
#: Positional-encoding frequencies of the atlas (u, v) and alpha (x, y, t) inputs.
ATLAS_FREQUENCIES, ALPHA_FREQUENCIES = 10, 5
#: Pixels per step of the mappings' calibration (at most the training batch).
PRETRAIN_MAX_BATCH = 10000
#: The calibration draws from its own random stream (the seed plus this), not the training sampler's.
PRETRAIN_SEED_OFFSET = 1


class PaperModel(AtlasModel):
    def __init__(self, cfg: FitConfig, size: tuple[int, int], frames: int, num_layers: int = 2) -> None:
        super().__init__()
        if num_layers != 2:
            raise ValueError("the paper model has exactly one background and one foreground layer")
        self.width, self.height = size
        self.frames = frames
        self.num_layers = 2
        self.scale = cfg.uv_mapping_scale
        self.map_bg = MLP(3, 2, HIDDEN, BG_MAPPING_LAYERS)
        self.map_fg = MLP(3, 2, HIDDEN, FG_MAPPING_LAYERS)
        self.pe_atlas = PositionalEncoding(ATLAS_FREQUENCIES)
        d_atlas = self.pe_atlas.out_dim(2)
        self.atlas = MLP(d_atlas, 3, HIDDEN, ATLAS_LAYERS, skips=ATLAS_SKIPS)
        self.pe_alpha = PositionalEncoding(ALPHA_FREQUENCIES)
        self.alpha_mlp = MLP(self.pe_alpha.out_dim(3), 1, HIDDEN, ALPHA_LAYERS)

    def uv(self, layer: int, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        net = self.map_bg if layer == 0 else self.map_fg
        return torch.tanh(net(self.normalized_xyt(xy, t)))

    def uv_per_px(self, layer: int) -> float:
        return self.scale / (max(self.width, self.height) / 2.0)

    def color(self, layer: int, uv: torch.Tensor) -> torch.Tensor:
        quadrant = uv * 0.5 + (0.5 if layer == 1 else -0.5)
        return (torch.tanh(self.atlas(self.pe_atlas(quadrant))) + 1.0) * 0.5

    def alpha(self, xy: torch.Tensor, t: torch.Tensor, uvs: list[torch.Tensor] | None = None) -> torch.Tensor:
        raw = torch.tanh(self.alpha_mlp(self.pe_alpha(self.normalized_xyt(xy, t))))
        a = ALPHA_FLOOR + ALPHA_SPAN * 0.5 * (raw + 1.0)
        return torch.cat((1.0 - a, a), -1)

    def param_groups(self, cfg: FitConfig) -> list[dict]:
        return [{"params": list(self.parameters()), "lr": cfg.lr, "name": "all"}]

    def prepare(self, cfg: FitConfig, device: torch.device) -> None:
        """Calibrate both mappings to scale * identity (the reference's pre-training)."""
        gen = torch.Generator(device="cpu").manual_seed(cfg.seed + PRETRAIN_SEED_OFFSET)
        n = min(cfg.batch, PRETRAIN_MAX_BATCH)
        for net in (self.map_fg, self.map_bg):
            opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
            for _ in range(cfg.pretrain_iters):
                xy = torch.rand(n, 2, generator=gen) * torch.tensor([self.width, self.height])
                t = torch.randint(0, self.frames, (n,), generator=gen)
                xyt = self.normalized_xyt(xy.to(device), t.to(device))
                loss = ((torch.tanh(net(xyt)) - self.scale * xyt[:, :2]) ** 2).sum(-1).mean()
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
