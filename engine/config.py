"""Fit configuration: one dataclass, named presets, CLI overrides, versioned JSON.

Presets are plain instances of ``FitConfig`` (nerfstudio's method_configs idea): a preset is a point in
the accuracy-vs-time trade-off, not a different code path. Every field can be overridden with
``--set key=value``; the resolved config is saved as JSON in the run folder so a run can be resumed and
reproduced exactly.
"""

from __future__ import annotations

import dataclasses
import difflib
import itertools
import json
import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from .contract import CLI_MODULE, PRESET_STEPS, SCHEMA_VERSION
from .errors import InputError

#: OpenCV DIS optical-flow presets (``flow_preset``), fastest first; engine/data/flow.py maps each to OpenCV's.
#: Named here so the config (and the add-on's tests on a Blender without OpenCV) need no cv2.
FLOW_PRESETS: tuple[str, ...] = ("ultrafast", "fast", "medium")


@dataclass
class FitConfig:
    """Everything that decides what a fit computes. Field docstrings are the ``--set`` help."""

    preset: str = "balanced"
    """Name of the preset this config started from (informational)."""
    model: str = "fast"
    """Architecture: ``fast`` (multi-resolution grids + small MLPs, the default) or ``paper`` (the paper's MLPs)."""
    steps: int = 6000
    """Optimisation steps."""
    batch: int = 4000
    """Random pixels per step, spread over all frames (the paper uses 10k; the fast model gains more from
    more steps than from bigger batches)."""
    object_sample_share: float = 0.0
    """Share of each step's pixels drawn from the masked objects and the ``mask_prior_margin_px`` band around
    them (the rest uniform over the clip): a small object gets enough samples for its mapping to track it."""
    seed: int = 0
    """Random seed (sampling and initialisation); the same seed gives the same result on CPU."""
    long_edge: int = 768
    """Working resolution: the clip is resized so its long edge has this many pixels (never enlarged)."""

    # --- preprocessing
    flow_preset: str = "medium"
    """OpenCV DIS preset for optical flow: ultrafast | fast | medium."""
    flow_threshold_px: float = 1.0
    """Forward-backward consistency threshold: flow with a larger round-trip error is not used."""

    # --- optimisation
    lr: float = 1e-3
    """Adam learning rate of the MLPs (paper model: all parameters, 1e-4)."""
    lr_grid: float = 1e-2
    """Adam learning rate of the grid features and per-frame motion (fast model)."""
    lr_final_ratio: float = 0.1
    """The learning rates decay exponentially to this fraction of their start by the last step."""

    # --- loss weights (the paper's, App. A and the reference config)
    w_rgb: float = 5000.0
    """Reconstruction: squared RGB error."""
    w_gradient: float = 1000.0
    """Reconstruction of image gradients (finite differences)."""
    w_sparsity: float = 1000.0
    """Sparsity ||(1-alpha) c_f||^2: the foreground atlas holds nothing where the foreground is absent."""
    w_atlas_sparsity: float = 10.0
    """Two or more foreground layers (paper Sec. 4.3): l1 on atlas colours at random atlas points replaces
    the sparsity term above (which would blacken what one object hides of another)."""
    atlas_sparsity_samples: int = 1024
    """Random atlas points per foreground layer per step for ``w_atlas_sparsity``."""
    w_flow: float = 5.0
    """Flow consistency of the mappings (alpha-weighted per layer), in pixels."""
    w_alpha_flow: float = 49.0
    """Flow consistency of alpha."""
    long_flow_max_gap: int = 0
    """Long-range correspondences: flow between frames 2, 4, 8, ... (powers of two up to this) apart, kept where
    it survives the forward-backward check, ties mappings that far apart directly, so small per-pair errors cannot
    add up to a drift over the clip (0 or 1: off; computed with the flow and cached)."""
    long_flow_samples: int = 1024
    """Long-range correspondences drawn per step (``object_sample_share`` of them on the objects)."""
    w_long_flow: float = 5.0
    """Flow consistency of the mappings over the long-range correspondences (as ``w_flow``: atlas distance in
    pixels, alpha-weighted per layer at the source pixel)."""
    long_flow_stride: int = 2
    """Long-range correspondences are kept on a pixel grid of this stride (memory: 1/stride^2 of the pixels)."""
    w_rigidity: float = 1.0
    """Local rigidity: symmetric Dirichlet energy of the mapping Jacobian (delta = rigidity_delta)."""
    rigidity_delta: float = 1.0
    """Finite-difference step of the local rigidity term, in working pixels."""
    w_global_rigidity_fg: float = 5.0
    """Global rigidity of the foreground mapping (bootstrap only)."""
    w_global_rigidity_bg: float = 50.0
    """Global rigidity of the background mapping (bootstrap only)."""
    global_rigidity_delta: float = 100.0
    """Finite-difference step of the global rigidity term, in working pixels."""
    global_rigidity_steps: int = 5000
    """Global rigidity is active for steps < this."""
    w_mask: float = 2000.0
    """Mask bootstrap: BCE between alpha and the masks, for steps < bootstrap_steps."""
    bootstrap_steps: int = 10000
    """Length of the mask bootstrap (paper: 10k of 400k steps)."""
    w_scribble: float = 2000.0
    """Scribbles (paper Sec. 4.4, ``fit --scribbles``): -log(alpha_i) at layer i's scribbled pixels, during the
    bootstrap only, like the mask term it refines (same weight: a scribble is as sure as a mask)."""
    scribble_samples: int = 512
    """Scribbled pixels drawn per step (they are too sparse to be hit often by the random pixel batch)."""
    scribble_carry: bool = False
    """The scribble term also at the strokes carried to every frame along the consistent flow (the labels that seed
    each part's motion, ``scribbles.propagate_labels``): the parts' ownership is held on the frames nobody
    scribbled, not only on the two or three that were. Off in every preset: on limbs_jump (three frames of strokes)
    it takes the limb from 0.87 to 0.96 but the body from 0.55 to 0.50 and 2.8 dB of PSNR, the carried labels being
    wrong where the parts cross (docs/bench/experiments.md)."""
    w_mask_prior: float = 0.0
    """After the bootstrap, a weak BCE far from the mask boundary keeps alpha from drifting (0 = paper)."""
    mask_prior_margin_px: float = 12.0
    """The mask prior ignores pixels closer than this to a mask boundary (masks are coarse hints)."""
    mask_hold_coverage: float = 0.4
    """After the bootstrap the mask prior holds only the pixels deeper inside a mask than ``mask_prior_margin_px``.
    A thin object (a dog's legs, a bike, a rider) has few such pixels, and its alpha then leaves the parts nothing
    holds. A mask layer whose prior keeps less than this share of its mask pixels as inside keeps the bootstrap's
    mask term (``w_mask``) for the whole fit (term ``mask_hold``; 0 = never). Thick objects (a swan, a car) are
    fitted as before."""
    mask_snap_px: int = 16
    """Loose masks: find, per mask layer, the offset (up to this many working pixels in or out) at which the masks'
    outline meets the clip's strongest edges, and move the masks there before fitting (engine/data/mask_snap.py;
    0 = fit the masks as drawn). A mask drawn 10 px wide otherwise teaches the foreground a ring of background;
    precise masks are left as they are."""

    w_anchor: float = 0.0
    """Fast model: squared pixels of a foreground mapping's mean drift (over the layer's mask pixels) from its
    flow-fitted start. A mapping is free to translate as a whole; with a bounded atlas that drift is not
    harmless: the part of the object that slides outside its atlas box lands on empty atlas, which is black (a
    free fit for a dark object), and the rest falls to the background. Only the mean is pinned, so no
    deformation is resisted (docs/engine.md has the drift and alpha IoU with and without it)."""

    # --- paper model
    uv_mapping_scale: float = 0.8
    """Paper model: atlas scale relative to the frame (the mappings are calibrated to scale*identity)."""
    pretrain_iters: int = 100
    """Paper model: calibration steps of the mappings to (scaled) identity before training."""

    # --- fast model
    mapping_hidden: int = 64
    """Fast model: width of the residual mapping MLP (no positional encoding: mappings stay smooth)."""
    mapping_layers: int = 3
    """Fast model: hidden layers of the residual mapping MLP."""
    atlas_levels: int = 6
    """Fast model: resolution levels of each layer's atlas grid (finest has ~1 texel per working pixel)."""
    atlas_features: int = 4
    """Fast model: features per atlas grid level."""
    atlas_density: float = 1.0
    """Fast model: finest atlas texels per working pixel."""
    alpha_levels: int = 5
    """Fast model: resolution levels of the alpha grid over (x, y, t)."""
    alpha_features: int = 2
    """Fast model: features per alpha grid level."""
    alpha_density: float = 0.25
    """Fast model: finest alpha grid cells per working pixel."""
    alpha_atlas_density: float = 0.0
    """Fast model: an opacity grid in each foreground layer's atlas, at this many finest cells per reference pixel,
    added to the (x, y, t) alpha's logit (0 = none). The (x, y, t) grid learns a thin part (a leg, a bike frame)
    separately in every frame, from the few samples that land on it there; in atlas space every frame's samples of
    that part train the same cells, so an object's shape is learned once and moves with its mapping."""
    alpha_atlas_levels: int = 3
    """Fast model: resolution levels of the atlas-space opacity grid (``alpha_atlas_density`` > 0)."""
    decoder_hidden: int = 64
    """Fast model: width of the colour and alpha decoder MLPs."""
    warp_levels: int = 2
    """Fast model: levels of the smooth per-frame warp grid added to each mapping (0 = similarity + MLP only)."""
    warp_foreground: bool = False
    """Fast model: give foreground mappings a warp grid too (off: it lets an object's mapping slide and
    paint would swim; the background's non-rigid water and foliage are where the warp pays)."""
    warp_cell_px: float = 8.0
    """Fast model: cell size, in working pixels, of the finest warp level (coarser levels double it)."""
    lr_warp: float = 0.01
    """Adam learning rate of the warp grid, in pixels per step (every fast preset: 0.05, see ``_fast``)."""
    init_motion: bool = True
    """Fast model: initialise each layer's per-frame motion from the optical flow (robust similarity fit)."""
    atlas_margin_fg: float = 0.06
    """Fast model: a foreground atlas's content rectangle is the object's extent (its masks, mapped by the
    initial motion) grown by this fraction; outside it the atlas is empty. Kept small: empty atlas inside the box
    is black, and a mapping that drifts into it fits dark content for free (``w_anchor`` pins that drift)."""

    # --- scene analysis (engine.data.scene_analysis)
    components: str = "auto"
    """``auto``: compute only what the scene calls for (a static camera gets a near-identity background
    mapping, a pan/zoom a similarity with a small residual and no warp grid; no foreground or alpha networks
    for a background-only clip; no flow for a single frame; loss terms without anything to act on are not
    evaluated). ``all``: every component on whatever the clip (to compare, or if the analysis is wrong for a
    clip). The decisions and their reasons are written to RUN_DIR/scene.json."""

    atlas_box_full_mask: bool = False
    """Fast model: a foreground atlas box spans the whole masks (True, every preset) rather than the eroded
    ones the motion is fitted on (False): the erosion keeps the motion fit off unreliable boundary flow, but a
    box drawn from it cuts the rim off small objects (a 30 px object loses 6 px on every side)."""

    # --- bookkeeping
    eval_every: int = 100
    """Steps between progress lines with PSNR on a fixed pixel sample."""
    eval_pixels: int = 20000
    """Size of the fixed pixel sample for the live PSNR."""
    checkpoint_seconds: float = 120.0
    """Wall-clock seconds between checkpoints (and one at the end and on SIGINT/SIGTERM)."""

    def to_json(self) -> str:
        return json.dumps({"schema": SCHEMA_VERSION, "config": dataclasses.asdict(self)}, indent=2)

    @classmethod
    def from_json(cls, text: str, path: str | Path | None = None) -> FitConfig:
        """A config as ``to_json`` wrote it; anything else (not JSON, not an object, another schema, an unknown
        field, a field of the wrong type or out of its range) is a one-line ``InputError`` naming ``path``. A field
        missing takes its ``LATER_FIELDS`` value, the one that computes what the engine that wrote the file did (a
        config.json of an earlier engine holds no later field), or else its default; a run's checkpoint records
        the config it was fitted with, so a value that differs from it is refused when the run loads."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError:
            raise InputError(path, "not valid JSON", CONFIG_FILE_FIX) from None
        if not isinstance(data, dict):
            raise InputError(path, "config is not a JSON object", CONFIG_FILE_FIX)
        if data.get("schema") != SCHEMA_VERSION:
            raise InputError(
                path,
                f"config schema {data.get('schema')!r} is not supported (this engine writes {SCHEMA_VERSION})",
                "fit into a new run folder or use the engine version that made this run",
            )
        values = data.get("config")
        if not isinstance(values, dict):
            raise InputError(path, "config has no 'config' object", CONFIG_FILE_FIX)
        # a field the file predates was fitted with the value that reproduces the engine that wrote it
        earlier = {k: v for k, v in LATER_FIELDS.items() if k not in values}
        return apply_overrides(cls(), {**earlier, **values}, source=path)


#: The fix for a config.json that is damaged or was edited into something the engine cannot fit with.
CONFIG_FILE_FIX = "restore it, or fit into a new run folder"
#: The largest int a field may take: torch sizes and generator seeds are 64-bit, and nothing a fit counts
#: (steps, pixels, layers) comes near it.
MAX_INT = 2**31 - 1
#: The smallest working long edge: below it a frame has too few pixels for the gradient and rigidity terms'
#: neighbours and for optical flow.
MIN_LONG_EDGE = 16


@dataclass(frozen=True)
class Valid:
    """A field's valid values: a number in [``low``, ``high``] (``above``: strictly above ``low``; None: no
    bound; numbers are always finite and ints at most ``MAX_INT``), or one of ``choices`` (a str field).
    bool fields take true or false, str fields without choices any one line of text."""

    low: float | None = None
    high: float | None = None
    above: bool = False
    choices: tuple[str, ...] = ()

    def accepts(self, value: Any) -> bool:
        if isinstance(value, str):
            return value in self.choices if self.choices else bool(value.strip()) and "\n" not in value
        if isinstance(value, bool):
            return True
        if not math.isfinite(value) or (isinstance(value, int) and abs(value) > MAX_INT):
            return False
        if self.low is not None and (value <= self.low if self.above else value < self.low):
            return False
        return self.high is None or value <= self.high

    def describe(self, kind: str) -> str:
        """The valid values in words: ``an int >= 1``, ``a number in 0..1``, ``one of fast, paper``."""
        if kind == "bool":
            return "true or false"
        if kind == "str":
            return f"one of {', '.join(self.choices)}" if self.choices else "one line of text"
        noun = "an int" if kind == "int" else "a finite number"
        low = None if self.low is None else _number(self.low, kind)
        high = None if self.high is None else _number(self.high, kind)
        if low is not None and high is not None and not self.above:
            return f"{noun} in {low}..{high}"
        bounds = [f"{'>' if self.above else '>='} {low}"] if low is not None else []
        bounds += [f"<= {high}"] if high is not None else []
        return f"{noun} {' and '.join(bounds)}" if bounds else noun


def _number(value: float, kind: str) -> str:
    return str(int(value)) if kind == "int" or float(value).is_integer() else repr(value)


#: The largest a loss weight (``w_*``) may be: 200 times the paper's largest (``w_rgb`` 5000). Adam divides each step
#: by the gradient's running size, so no balance of terms needs a larger one; far beyond it a weight overflows
#: float32 (1e308 is Inf there: the first loss is Inf and the fit diverges whatever its learning rate).
MAX_LOSS_WEIGHT = 1e6

_POSITIVE = Valid(low=0, above=True)
_NON_NEGATIVE = Valid(low=0)
#: A loss weight: finite, >= 0 (0 turns its term off) and at most MAX_LOSS_WEIGHT.
_WEIGHT = Valid(low=0, high=MAX_LOSS_WEIGHT)
_AT_LEAST_ONE = Valid(low=1)
_FRACTION = Valid(low=0, high=1)
_ANY = Valid()

#: Every field's valid values (``--help-config`` shows them; ``check_config`` and ``apply_overrides`` enforce
#: them, for ``--set`` and for a run's config.json alike, before anything is written).
VALID: dict[str, Valid] = {
    "preset": _ANY,
    "model": Valid(choices=("fast", "paper")),
    "steps": _AT_LEAST_ONE,
    "batch": _AT_LEAST_ONE,
    "object_sample_share": _FRACTION,
    "seed": _NON_NEGATIVE,
    "long_edge": Valid(low=MIN_LONG_EDGE),
    "flow_preset": Valid(choices=FLOW_PRESETS),
    "flow_threshold_px": _POSITIVE,
    "lr": _POSITIVE,
    "lr_grid": _POSITIVE,
    "lr_final_ratio": Valid(low=0, high=1, above=True),
    "w_rgb": _WEIGHT,
    "w_gradient": _WEIGHT,
    "w_sparsity": _WEIGHT,
    "w_atlas_sparsity": _WEIGHT,
    "atlas_sparsity_samples": _AT_LEAST_ONE,
    "w_flow": _WEIGHT,
    "w_alpha_flow": _WEIGHT,
    "long_flow_max_gap": _NON_NEGATIVE,
    "long_flow_samples": _AT_LEAST_ONE,
    "w_long_flow": _WEIGHT,
    "long_flow_stride": _AT_LEAST_ONE,
    "w_rigidity": _WEIGHT,
    "rigidity_delta": _POSITIVE,
    "w_global_rigidity_fg": _WEIGHT,
    "w_global_rigidity_bg": _WEIGHT,
    "global_rigidity_delta": _POSITIVE,
    "global_rigidity_steps": _NON_NEGATIVE,
    "w_mask": _WEIGHT,
    "bootstrap_steps": _NON_NEGATIVE,
    "w_scribble": _WEIGHT,
    "scribble_samples": _AT_LEAST_ONE,
    "w_mask_prior": _WEIGHT,
    "mask_prior_margin_px": _NON_NEGATIVE,
    "mask_hold_coverage": _FRACTION,
    "mask_snap_px": _NON_NEGATIVE,
    "w_anchor": _WEIGHT,
    "uv_mapping_scale": Valid(low=0, high=1, above=True),
    "pretrain_iters": _NON_NEGATIVE,
    "mapping_hidden": _AT_LEAST_ONE,
    "mapping_layers": _AT_LEAST_ONE,
    "atlas_levels": _AT_LEAST_ONE,
    "atlas_features": _AT_LEAST_ONE,
    "atlas_density": _POSITIVE,
    "alpha_levels": _AT_LEAST_ONE,
    "alpha_features": _AT_LEAST_ONE,
    "alpha_density": _POSITIVE,
    "alpha_atlas_density": _NON_NEGATIVE,
    "alpha_atlas_levels": _AT_LEAST_ONE,
    "decoder_hidden": _AT_LEAST_ONE,
    "warp_levels": _NON_NEGATIVE,
    "warp_foreground": _ANY,
    "scribble_carry": _ANY,
    "warp_cell_px": _POSITIVE,
    "lr_warp": _POSITIVE,
    "init_motion": _ANY,
    "atlas_margin_fg": _NON_NEGATIVE,
    "components": Valid(choices=("auto", "all")),
    "atlas_box_full_mask": _ANY,
    "eval_every": _AT_LEAST_ONE,
    "eval_pixels": _AT_LEAST_ONE,
    "checkpoint_seconds": _NON_NEGATIVE,
}

#: What ``fit --resume --set`` may change: the schedule (its length and learning rates: a fit that diverged
#: continues from its last good checkpoint with a lower rate) and the bookkeeping. Anything else decides what
#: the fit computes, so a resume that changes it would not continue the same fit: it is refused.
RESUMABLE_FIELDS: tuple[str, ...] = (
    "steps",
    "lr",
    "lr_grid",
    "lr_warp",
    "lr_final_ratio",
    "eval_every",
    "eval_pixels",
    "checkpoint_seconds",
)
#: Fields that decide only how a new fit starts (the fast model's starting motions and atlas boxes, the paper
#: model's calibration): a checkpoint carries their result, so a run loaded from its folder never reads them,
#: and a checkpoint and a config.json that differ only there still belong together.
START_FIELDS: tuple[str, ...] = ("init_motion", "atlas_margin_fg", "atlas_box_full_mask", "pretrain_iters")
#: Fields added since checkpoints record their config, each with the value that computes what the engine did
#: before it: a checkpoint saved without the field was fitted with that value (``check_checkpoint_belongs``), so
#: the runs made before it still load, resume and export.
LATER_FIELDS: dict[str, Any] = {
    "long_flow_max_gap": 0,
    "long_flow_samples": 1024,
    "w_long_flow": 5.0,
    "long_flow_stride": 2,
    "mask_snap_px": 0,
    "alpha_atlas_density": 0.0,
    "alpha_atlas_levels": 3,
    "mask_hold_coverage": 0.0,
    "scribble_carry": False,
}
#: The learning rates (``fit`` names them when a fit diverges).
LR_FIELDS: tuple[str, ...] = ("lr", "lr_grid", "lr_warp")


def loss_weights(cfg: FitConfig, step: int) -> dict[str, float]:
    """Every loss term's weight at ``step``: global rigidity and the mask bootstrap (with the scribbles that
    refine it) end at their step counts, where the mask prior takes over from the bootstrap (and, for small and thin
    objects' mask layers, the mask term goes on: ``mask_hold``). The weights change only at those two steps."""
    boot = step < cfg.bootstrap_steps
    glob = step < cfg.global_rigidity_steps
    return {
        "rgb": cfg.w_rgb,
        "gradient": cfg.w_gradient,
        "rigidity": cfg.w_rigidity,
        "global_rigidity_bg": cfg.w_global_rigidity_bg if glob else 0.0,
        "global_rigidity_fg": cfg.w_global_rigidity_fg if glob else 0.0,
        "flow": cfg.w_flow,
        "alpha_flow": cfg.w_alpha_flow,
        "long_flow": cfg.w_long_flow,
        "sparsity": cfg.w_sparsity,
        "mask": cfg.w_mask if boot else 0.0,
        "mask_prior": 0.0 if boot else cfg.w_mask_prior,
        "mask_hold": 0.0 if boot else cfg.w_mask,
        "atlas_sparsity": cfg.w_atlas_sparsity,
        "scribble": cfg.w_scribble if boot else 0.0,
        "anchor": cfg.w_anchor,
    }


def weight_ever_on(cfg: FitConfig, term: str) -> bool:
    """Whether ``term`` has a non-zero weight at some step of the fit (``loss_weights`` at each of its phases)."""
    phases = {0} | {s for s in (cfg.bootstrap_steps, cfg.global_rigidity_steps) if 0 < s < cfg.steps}
    return any(loss_weights(cfg, step)[term] != 0.0 for step in phases)


def _field_doc_names() -> list[str]:
    return [f.name for f in fields(FitConfig)]


def field_kind(name: str) -> str:
    """A field's type as a word: ``int``, ``float``, ``bool`` or ``str``."""
    kind = FitConfig.__dataclass_fields__[name].type
    return kind if isinstance(kind, str) else getattr(kind, "__name__", str(kind))


def _parse_value(kind: str, raw: str, key: str) -> Any:
    """A ``--set`` string as a value of ``kind``; a one-line error when it is not one."""
    try:
        if kind == "bool":
            low = raw.lower()
            if low in ("1", "true", "yes", "on"):
                return True
            if low in ("0", "false", "no", "off"):
                return False
            raise ValueError(raw)
        if kind == "int":
            value = float(raw)
            if not value.is_integer():
                raise ValueError(raw)
            return int(value)
        if kind == "float":
            return float(raw)
    except (ValueError, OverflowError):
        article = "an" if kind[:1] in "aeiou" else "a"
        raise InputError(None, f"--set {key}={raw}: not a valid {kind}", f"give {key} {article} {kind} value") from None
    return raw


def _typed(kind: str, value: Any) -> Any:
    """``value`` as ``kind`` when it is one (an int counts as a float, a whole float as an int); else None."""
    if isinstance(value, bool):
        return value if kind == "bool" else None
    if kind == "int":
        if isinstance(value, float) and math.isfinite(value) and value.is_integer():
            return int(value)
        return value if isinstance(value, int) else None
    if kind == "float":
        return float(value) if isinstance(value, (int, float)) else None
    return value if kind == "str" and isinstance(value, str) else None


#: Where a value being checked came from: ``--set`` on the command line (its messages quote the argument).
FROM_SET = "--set"


def check_value(key: str, value: Any, source: str | Path | None = None, raw: Any = None) -> Any:
    """``value`` of field ``key`` checked against its type and ``VALID`` range (returned as its type), or a
    one-line ``InputError``: quoting ``--set key=raw`` when ``source`` is ``FROM_SET``, naming the file when it is
    a path (a run's config.json), and the field alone when None (a config built in code)."""
    kind = field_kind(key)
    valid = VALID[key]
    typed = _typed(kind, value)
    if typed is not None and valid.accepts(typed):
        return typed
    want = valid.describe(kind)
    if isinstance(typed, int) and not isinstance(typed, bool) and abs(typed) > MAX_INT:
        want += f" (at most {MAX_INT})"
    fix = f"`python -m {CLI_MODULE} fit --help-config` lists every field's range"
    if source == FROM_SET:
        shown = value if raw is None else raw
        raise InputError(None, f"--set {key}={shown}: {key} must be {want}", fix)
    if source is None:
        raise InputError(None, f"config {key!r} must be {want}, not {value!r}", fix)
    raise InputError(source, f"config {key!r} must be {want}, not {value!r}", CONFIG_FILE_FIX)


def check_config(cfg: FitConfig, source: str | Path | None = None) -> FitConfig:
    """Every field of ``cfg`` within its type and range (``VALID``), or a one-line ``InputError`` (``source``: the
    file it came from, if any): the one check a config passes before a fit writes anything."""
    for f in fields(FitConfig):
        check_value(f.name, getattr(cfg, f.name), source)
    return cfg


def apply_overrides(cfg: FitConfig, overrides: dict[str, Any], source: str | Path | None = None) -> FitConfig:
    """Return a copy of ``cfg`` with ``overrides`` applied; unknown keys suggest the nearest field, and every
    value is checked against its type and range (``check_value``). ``source``: the file the overrides come from;
    None: ``--set`` strings (``"1e3"``, ``"true"``) or values given in code."""
    names = _field_doc_names()
    values: dict[str, Any] = {}
    for key, raw in overrides.items():
        if key not in VALID:
            near = difflib.get_close_matches(str(key), names, n=1)
            hint = f"did you mean {near[0]!r}?" if near else f"see `python -m {CLI_MODULE} fit --help-config`"
            raise InputError(source, f"unknown config key {key!r}", hint)
        if source is None and isinstance(raw, str):
            values[key] = check_value(key, _parse_value(field_kind(key), raw, key), FROM_SET, raw)
        else:
            values[key] = check_value(key, raw, source)
    return dataclasses.replace(cfg, **values)


def resume_changes(saved: FitConfig, new: FitConfig) -> tuple[list[str], list[str]]:
    """The fields ``new`` changes from ``saved``: (those a resume may change, those it may not)."""
    changed = [f.name for f in fields(FitConfig) if getattr(saved, f.name) != getattr(new, f.name)]
    allowed = [name for name in changed if name in RESUMABLE_FIELDS]
    return allowed, [name for name in changed if name not in RESUMABLE_FIELDS]


def parse_set_args(items: list[str]) -> dict[str, str]:
    """``["steps=100", "w_rgb=1e3"]`` -> dict; a malformed item is a one-line error."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError(None, f"--set {item!r} is not key=value", "write e.g. --set steps=2000")
        out[key.strip()] = value.strip()
    return out


def _fast(**kw: Any) -> FitConfig:
    """The fast model's presets share these. lr_warp: the background's warp grid is where a deformable
    background (water, foliage) gains its PSNR, and it needs a faster rate than the MLPs to get there; decaying
    it towards zero gives the gain back (docs/engine.md). object_sample_share: a quarter of each batch on the
    objects lets a small object's mapping follow it, at little cost to the background
    (docs/bench/experiments.md). w_anchor 2: it still holds a mapping in its atlas box (the swan's drift), and
    it holds a start that loose masks put off less firmly than 10 did (docs/bench/experiments.md)."""
    fast = FitConfig(
        model="fast",
        w_mask_prior=20.0,
        w_anchor=2.0,
        atlas_box_full_mask=True,
        lr_warp=0.05,
        object_sample_share=0.25,
    )
    return dataclasses.replace(fast, **kw)


#: Named presets; their step budgets are the contract's (``PRESET_STEPS``: the add-on's menu reads them too).
PRESETS: dict[str, FitConfig] = {
    # draft: the masks (snapped) are fitted for all of its steps; let go after 300, the alpha dropped the parts the
    # prior does not hold (a swan's neck, a dog's legs) and tracking on them with it (docs/bench/experiments.md)
    "draft": _fast(
        preset="draft",
        steps=PRESET_STEPS["draft"],
        bootstrap_steps=PRESET_STEPS["draft"],
        global_rigidity_steps=150,
    ),
    "balanced": _fast(
        preset="balanced", steps=PRESET_STEPS["balanced"], bootstrap_steps=2000, global_rigidity_steps=1000
    ),
    # final: its long schedule leaves the alpha free for most of the fit after the bootstrap; that long with the
    # balanced bootstrap and prior, the alpha takes reflections and haze into the foreground (the reconstruction
    # gains more than the prior costs: docs/engine.md). The paper's 10000-step bootstrap and a prior ten times
    # stronger make that trade a loss.
    "final": _fast(
        preset="final",
        steps=PRESET_STEPS["final"],
        bootstrap_steps=10000,
        global_rigidity_steps=2500,
        w_mask_prior=200.0,
    ),
    "paper": FitConfig(
        preset="paper",
        model="paper",
        steps=PRESET_STEPS["paper"],
        batch=10000,
        lr=1e-4,
        lr_final_ratio=1.0,
        bootstrap_steps=10000,
        global_rigidity_steps=5000,
        w_mask_prior=0.0,
        mask_hold_coverage=0.0,
        init_motion=False,
    ),
}


def preset_config(name: str) -> FitConfig:
    """The preset called ``name``; an unknown name suggests the nearest one."""
    if name not in PRESETS:
        near = difflib.get_close_matches(name, list(PRESETS), n=1)
        hint = f"did you mean {near[0]!r}?" if near else f"choose one of {', '.join(PRESETS)}"
        raise InputError(None, f"unknown preset {name!r}", hint)
    return dataclasses.replace(PRESETS[name])


def config_help() -> str:
    """Every field with its type, default and docstring, for ``--help-config``."""
    import ast
    import inspect

    (cls,) = ast.parse(inspect.getsource(FitConfig)).body
    assert isinstance(cls, ast.ClassDef)
    docs: dict[str, str] = {}
    for node, nxt in itertools.pairwise(cls.body):
        doc = nxt.value if isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant) else None
        if doc is not None and isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            docs[node.target.id] = str(doc.value)
    default = FitConfig()
    lines = []
    for f in fields(FitConfig):
        kind = field_kind(f.name)
        valid = VALID[f.name].describe(kind)
        resumable = ", resumable" if f.name in RESUMABLE_FIELDS else ""
        lines.append(
            f"  {f.name} ({kind}, default {getattr(default, f.name)!r}, {valid}{resumable}): {docs.get(f.name, '')}"
        )
    resumable_note = (
        f"resumable: `fit --resume --set` may change only {', '.join(RESUMABLE_FIELDS)}; "
        "any other field starts a new fit (a new --out, or --refit)"
    )
    return "\n".join([*lines, "", resumable_note])


__all__ = [
    "LATER_FIELDS",
    "LR_FIELDS",
    "PRESETS",
    "RESUMABLE_FIELDS",
    "START_FIELDS",
    "VALID",
    "FitConfig",
    "Valid",
    "apply_overrides",
    "check_config",
    "check_value",
    "config_help",
    "field_kind",
    "loss_weights",
    "parse_set_args",
    "preset_config",
    "resume_changes",
    "weight_ever_on",
]
