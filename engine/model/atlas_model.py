"""Layered atlas models: the interface the objective uses, and the fast default model.

Coordinates everywhere are continuous working-resolution pixels (pixel i's centre is i + 0.5) and
integer frame indices; each model owns its normalisation. Layer 0 is the background, layers 1.. are
foreground objects. ``alpha`` returns per-layer weights that sum to one (for two layers: 1-a, a).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..config import FitConfig
from ..data.video import far_outside, mask_core
from ..terms.run_folder import BG_MOTION_DEFORMABLE, BG_MOTION_PAN_ZOOM, BG_MOTION_STATIC
from .fields import MLP, Grid2D, Grid3D, level_resolutions
from .motion_init import LayerMotion

#: Alpha is squeezed into [ALPHA_FLOOR, ALPHA_FLOOR + ALPHA_SPAN] like the reference (0.001 .. 0.991),
#: so log(alpha) and log(1 - alpha) stay finite without relying on clamps.
ALPHA_FLOOR = 0.001
ALPHA_SPAN = 0.99
#: The finest alpha grid has at least this many cells along the long edge (all pixels if the clip is smaller).
ALPHA_MIN_CELLS = 128
#: The atlas-space opacity's coarsest level, in cells along the atlas's long side: a coarse object silhouette.
ALPHA_ATLAS_COARSEST = 8
#: Pan/zoom background (engine.data.scene_analysis): the per-frame similarity carries the camera; a residual MLP this
#: narrow and shallow only absorbs lens distortion and rolling shutter, at a fraction of the default's cost.
PANZOOM_MAPPING_HIDDEN = 16
PANZOOM_MAPPING_LAYERS = 1
#: Mapping kinds (terms.run_folder.BG_MOTION_*): what a layer's mapping is built from.
MAPPING_DEFORMABLE = BG_MOTION_DEFORMABLE
MAPPING_PAN_ZOOM = BG_MOTION_PAN_ZOOM
MAPPING_STATIC = BG_MOTION_STATIC


class AtlasModel(nn.Module):
    """What the objective needs from a model; subclasses implement the fields."""

    num_layers: int
    width: int
    height: int
    frames: int
    #: Loss terms the objective evaluates for this model (engine.data.scene_analysis decides them from the clip); None =
    #: every term. It lives on the model because the model was built for that scene: a term for a component
    #: the model does not have (sparsity without a foreground) has nothing to act on.
    active_terms: frozenset[str] | None = None
    #: Whether ``alpha`` reads the layers' atlas coordinates (then a caller that has them passes them).
    alpha_reads_uv: bool = False

    def uv(self, layer: int, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Atlas coordinates [N, 2] (roughly in [-1, 1]) of working pixels ``xy`` [N, 2] at frames ``t`` [N]."""
        raise NotImplementedError

    def uv_per_px(self, layer: int) -> float:
        """Atlas units per frame pixel of a rigid (rotation) mapping: converts atlas distances to pixels."""
        raise NotImplementedError

    def color(self, layer: int, uv: torch.Tensor) -> torch.Tensor:
        """Atlas colour [N, 3] in [0, 1] at atlas coordinates ``uv``."""
        raise NotImplementedError

    def uv_anchor(self, layer: int, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor | None:
        """The layer's initial (flow-fitted) mapping, if the model has one: the gauge the atlas is drawn in."""
        return None

    def alpha(self, xy: torch.Tensor, t: torch.Tensor, uvs: list[torch.Tensor] | None = None) -> torch.Tensor:
        """Per-layer opacity weights [N, L], summing to one. ``uvs``: each layer's ``uv(layer, xy, t)`` when the
        caller has already computed them (an alpha that reads atlas coordinates then need not map again)."""
        raise NotImplementedError

    def atlas_extent(self, layer: int) -> tuple[float, float]:
        """Half-width and half-height of the atlas region that can hold colour (random atlas samples are
        drawn there: the multi-layer sparsity term); the whole [-1, 1] square unless a model knows better."""
        return 1.0, 1.0

    def param_groups(self, cfg: FitConfig) -> list[dict]:
        raise NotImplementedError

    def prepare(self, cfg: FitConfig, device: torch.device) -> None:
        """Optional calibration before training (the paper model pre-trains its mappings)."""

    @torch.no_grad()
    def reconstruct(self, xy: torch.Tensor, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Composite colour [N, 3] and weights [N, L], without gradients."""
        w = self.alpha(xy, t)
        rgb = sum(w[:, i : i + 1] * self.color(i, self.uv(i, xy, t)) for i in range(self.num_layers))
        return rgb, w

    def normalized_xyt(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """The reference's normalisation: x and y by half the larger side (isotropic), t by half the length."""
        half = max(self.width, self.height) / 2.0
        tn = t.to(xy.dtype) / max(self.frames / 2.0, 0.5) - 1.0
        return torch.cat((xy / half - 1.0, tn[:, None]), dim=-1)


def _sum_levels(px: torch.Tensor) -> torch.Tensor:
    """Grid3D concatenates levels ([N, 2 * L]); the warp is the sum of their (dx, dy)."""
    return px.view(px.shape[0], -1, 2).sum(1)


def _alpha_from_logit(logit: torch.Tensor) -> torch.Tensor:
    return ALPHA_FLOOR + ALPHA_SPAN * torch.sigmoid(logit)


class FastLayerMapping(nn.Module):
    """Per-frame similarity (initialised from flow) + a smooth residual MLP on raw (x, y, t).

    No positional encoding of (x, y, t): the mapping must stay smooth so the atlas stays coherent.
    ``kind`` (engine.data.scene_analysis) sizes it to the motion: ``deformable`` is the full mapping (+ warp grid when
    ``warp``); ``pan_zoom`` keeps a small residual MLP and no warp grid; ``static`` is the per-frame affine
    correction alone (a tripod: nothing else can move the background, and nothing else is evaluated).
    """

    def __init__(
        self,
        motion: LayerMotion,
        size: tuple[int, int],
        frames: int,
        cfg: FitConfig,
        warp: bool = True,
        kind: str = MAPPING_DEFORMABLE,
        hidden: int | None = None,
    ) -> None:
        """``hidden``: the residual MLP's width (None: ``cfg.mapping_hidden``)."""
        super().__init__()
        w, h = size
        layers = cfg.mapping_layers
        hidden = cfg.mapping_hidden if hidden is None else hidden
        if kind == MAPPING_PAN_ZOOM:
            hidden, layers = PANZOOM_MAPPING_HIDDEN, PANZOOM_MAPPING_LAYERS
        self.kind = kind
        self.register_buffer("to_ref", torch.tensor(motion.to_ref, dtype=torch.float32))
        self.register_buffer("center", torch.tensor(motion.center, dtype=torch.float32))
        self.half_extent = float(motion.half_extent)
        self.delta = nn.Parameter(torch.zeros(frames, 2, 3))
        self.residual = None if kind == MAPPING_STATIC else MLP(3, 2, hidden, layers + 1, zero_last=True)
        self.half = max(w, h) / 2.0
        self.size = (w, h)
        self.frames = frames
        # t's step per frame: a clip longer than cfg.mapping_time_frames keeps the step a clip that long has
        span = frames if cfg.mapping_time_frames <= 0 else min(frames, cfg.mapping_time_frames)
        self.t_scale = max(span / 2.0, 0.5)
        self.t_offset = frames / 2.0 / self.t_scale
        # a coarse per-frame displacement field (pixels) for non-rigid motion the MLP is too smooth for;
        # cells of several pixels keep it low-frequency, and the rigidity terms keep it regular
        self.warp: Grid3D | None = None
        if warp and kind == MAPPING_DEFORMABLE and cfg.warp_levels > 0:
            res = []
            for i in range(cfg.warp_levels):
                cell = cfg.warp_cell_px * 2.0 ** (cfg.warp_levels - 1 - i)
                res.append((max(2, math.ceil(w / cell) + 1), max(2, math.ceil(h / cell) + 1), max(1, frames)))
            self.warp = Grid3D(res, 2, init_std=0.0)

    def initial(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """The flow-fitted similarity alone: where the mapping starts, and the frame its atlas box is drawn in."""
        a = self.to_ref[t]  # [N, 2, 3] frame px -> reference px
        ref = torch.einsum("nij,nj->ni", a[:, :, :2], xy) + a[:, :, 2]
        return (ref - self.center) / self.half_extent

    def forward(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        # delta is in atlas units per normalised pixel, so Adam's step size means the same at any resolution
        uv = self.initial(xy, t)
        xn = xy / self.half - 1.0
        tn = t.to(xy.dtype) / self.t_scale - self.t_offset
        d = self.delta[t]
        uv = uv + torch.einsum("nij,nj->ni", d[:, :, :2], xn) + d[:, :, 2]
        if self.residual is not None:
            uv = uv + self.residual(torch.cat((xn, tn[:, None]), -1))
        if self.warp is not None:
            w, h = self.size
            g = torch.stack(
                (
                    xy[:, 0] / (w / 2.0) - 1.0,
                    xy[:, 1] / (h / 2.0) - 1.0,
                    t.to(xy.dtype) / max(self.frames - 1, 1) * 2.0 - 1.0,
                ),
                -1,
            )
            px = self.warp(g).float()
            uv = uv + _sum_levels(px) / self.half_extent
        return uv


class FastAtlas(nn.Module):
    """One layer's atlas colours: multi-resolution 2D grids + a small decoder (sigmoid output).

    The grids cover only the content's rectangle [-ax, ax] x [-ay, ay] of the atlas square, at about
    ``atlas_density`` texels per reference pixel on the finest level. Outside that rectangle the atlas is
    empty (black): a pixel mapped there gets no colour and trains no texel, so the many frame pixels that
    a small object's mapping sends off its atlas cannot drag the border texels (and the decoder) to black.
    """

    def __init__(self, motion: LayerMotion, cfg: FitConfig) -> None:
        super().__init__()
        ax, ay = motion.aspect
        finest = math.ceil(2.0 * motion.half_extent * max(ax, ay) * cfg.atlas_density)
        res = level_resolutions(finest, cfg.atlas_levels)
        self.register_buffer("inv_aspect", torch.tensor([1.0 / ax, 1.0 / ay], dtype=torch.float32))
        self.grid = Grid2D([(max(2, round(r * ax)), max(2, round(r * ay))) for r in res], cfg.atlas_features)
        self.decoder = MLP(self.grid.out_dim, 3, cfg.decoder_hidden, 3)

    def forward(self, uv: torch.Tensor) -> torch.Tensor:
        g = uv * self.inv_aspect
        inside = (g.abs() <= 1.0).all(-1, keepdim=True)
        return torch.sigmoid(self.decoder(self.grid(g)).float()) * inside


class AtlasOpacity(nn.Module):
    """One foreground layer's opacity logit as a texture in its atlas: multi-resolution scalar grids over the layer's
    atlas rectangle, summed (no decoder: a logit texture needs none, and it costs one bilinear lookup per level).

    Every frame's samples of a part of the object train the same cells, once the mapping carries the part there; a
    thin part that the (x, y, t) grid sees a few pixels of per frame is learned from all of them. It starts at zero,
    so a fit starts from the same alpha as without it. Outside the rectangle the border cells extend outwards
    (``grid_sample``'s border padding): the object's atlas ends there, and the (x, y, t) alpha decides."""

    def __init__(self, motion: LayerMotion, cfg: FitConfig) -> None:
        super().__init__()
        ax, ay = motion.aspect
        finest = math.ceil(2.0 * motion.half_extent * max(ax, ay) * cfg.alpha_atlas_density)
        res = level_resolutions(finest, cfg.alpha_atlas_levels, coarsest=ALPHA_ATLAS_COARSEST)
        self.register_buffer("inv_aspect", torch.tensor([1.0 / ax, 1.0 / ay], dtype=torch.float32))
        self.grid = Grid2D([(max(2, round(r * ax)), max(2, round(r * ay))) for r in res], 1, init_std=0.0)

    def forward(self, uv: torch.Tensor) -> torch.Tensor:
        return self.grid(uv * self.inv_aspect).float().sum(-1, keepdim=True)


class FastModel(AtlasModel):
    """The default: quality per CPU-second. Same inputs, outputs and losses as the paper's model."""

    def __init__(
        self,
        cfg: FitConfig,
        size: tuple[int, int],
        frames: int,
        motions: list[LayerMotion],
        background: str = MAPPING_DEFORMABLE,
        alpha_network: bool = True,
    ) -> None:
        """``background``: the background mapping's kind (scene analysis); ``alpha_network=False`` (one layer
        only) builds no alpha grid or decoder: the single layer's alpha is 1 everywhere."""
        super().__init__()
        self.width, self.height = size
        self.frames = frames
        self.num_layers = len(motions)
        self.layer_motions = list(motions)  # saved in checkpoints: a reload rebuilds the same shapes
        if not alpha_network and self.num_layers > 1:
            raise ValueError("a model with foreground layers needs its alpha network")
        self.mappings = nn.ModuleList(
            FastLayerMapping(
                m,
                size,
                frames,
                cfg,
                warp=(i == 0 or cfg.warp_foreground),
                kind=background if i == 0 else MAPPING_DEFORMABLE,
                hidden=None if i == 0 else (cfg.mapping_hidden_fg or None),
            )
            for i, m in enumerate(motions)
        )
        self.atlases = nn.ModuleList(FastAtlas(m, cfg) for m in motions)
        self.alpha_grid: Grid3D | None = None
        self.alpha_decoder: MLP | None = None
        self.alpha_atlas: nn.ModuleList | None = None
        if not alpha_network:
            return
        # small clips keep a usable alpha resolution: at least ALPHA_MIN_CELLS on the long edge (or every pixel)
        long_edge = max(self.width, self.height)
        density = max(cfg.alpha_density, min(1.0, ALPHA_MIN_CELLS / long_edge))
        fw = max(2, round(self.width * density))
        fh = max(2, round(self.height * density))
        levels = max(1, cfg.alpha_levels)
        res3 = []
        for i in range(levels):
            s = 0.5 ** (levels - 1 - i)
            res3.append((max(2, round(fw * s)), max(2, round(fh * s)), max(1, min(frames, round(frames * s * 2)))))
        self.alpha_grid = Grid3D(sorted(set(res3)), cfg.alpha_features)
        n_out = 1 if self.num_layers == 2 else self.num_layers
        self.alpha_decoder = MLP(self.alpha_grid.out_dim, n_out, cfg.decoder_hidden, 2)
        if cfg.alpha_atlas_density > 0:  # built last: the other fields start as they do without it
            self.alpha_atlas = nn.ModuleList(AtlasOpacity(m, cfg) for m in motions[1:])
            self.alpha_reads_uv = True

    def uv(self, layer: int, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return self.mappings[layer](xy, t)

    def uv_per_px(self, layer: int) -> float:
        return 1.0 / self.mappings[layer].half_extent

    def color(self, layer: int, uv: torch.Tensor) -> torch.Tensor:
        return self.atlases[layer](uv)

    def uv_anchor(self, layer: int, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return self.mappings[layer].initial(xy, t)

    def atlas_extent(self, layer: int) -> tuple[float, float]:
        inv = self.atlases[layer].inv_aspect
        return 1.0 / float(inv[0]), 1.0 / float(inv[1])

    def alpha(self, xy: torch.Tensor, t: torch.Tensor, uvs: list[torch.Tensor] | None = None) -> torch.Tensor:
        if self.alpha_grid is None or self.alpha_decoder is None:
            return torch.ones((xy.shape[0], 1), dtype=torch.float32, device=xy.device)
        xn = xy[:, 0:1] / (self.width / 2.0) - 1.0
        yn = xy[:, 1:2] / (self.height / 2.0) - 1.0
        tn = (t.to(xy.dtype)[:, None] / max(self.frames - 1, 1)) * 2.0 - 1.0
        logits = self.alpha_decoder(self.alpha_grid(torch.cat((xn, yn, tn), -1))).float()
        if self.alpha_atlas is not None:
            # each foreground's atlas opacity at where its mapping sends the pixel (gradients reach the mapping
            # too: a part the opacity holds is a part the mapping must keep in place)
            at = [self.mappings[i](xy, t) if uvs is None else uvs[i] for i in range(1, self.num_layers)]
            own = torch.cat([op(uv) for op, uv in zip(self.alpha_atlas, at, strict=True)], -1)
            logits = logits + own if self.num_layers == 2 else logits + F.pad(own, (1, 0))
        if self.num_layers == 2:
            a = _alpha_from_logit(logits)
            return torch.cat((1.0 - a, a), -1)
        return torch.softmax(logits, -1)

    def param_groups(self, cfg: FitConfig) -> list[dict]:
        alpha_grid = [] if self.alpha_grid is None else list(self.alpha_grid.parameters())
        alpha_grid += [] if self.alpha_atlas is None else list(self.alpha_atlas.parameters())
        alpha_mlp = [] if self.alpha_decoder is None else list(self.alpha_decoder.parameters())
        grids = alpha_grid + [p for a in self.atlases for p in a.grid.parameters()]
        mlps = alpha_mlp + [p for a in self.atlases for p in a.decoder.parameters()]
        warps = [p for m in self.mappings if m.warp is not None for p in m.warp.parameters()]
        ids = {id(p) for p in warps}
        mapping = [p for m in self.mappings for p in m.parameters() if id(p) not in ids]
        groups = [
            {"params": grids, "lr": cfg.lr_grid, "name": "grids"},
            {"params": mlps, "lr": cfg.lr, "name": "decoders"},
            {"params": mapping, "lr": cfg.lr, "name": "mappings"},
        ]
        if warps:
            groups.append({"params": warps, "lr": cfg.lr_warp, "name": "warps"})
        return groups


def motion_regions(masks: np.ndarray, margin_px: float = 6.0) -> tuple[np.ndarray, list[np.ndarray]]:
    """Regions for motion estimation, away from mask boundaries where flow is unreliable: background = outside
    every mask by ``margin_px``; each foreground = its mask shrunk by ``margin_px``, or to ``video.CORE_FRACTION`` of
    the object's thickness when it is small, so small objects keep enough flow vectors (``mask_core``)."""
    bg = np.ones(masks.shape[1:], dtype=bool)
    fgs = []
    for layer in masks:
        ero = np.zeros_like(layer)
        for t, m in enumerate(layer):
            if not m.any():
                continue
            ero[t] = mask_core(m, margin_px)
            bg[t] &= far_outside(m, margin_px)
        fgs.append(ero)
    return bg, fgs
