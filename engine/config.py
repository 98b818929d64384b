"""Fit configuration: one declared dataclass, named presets, CLI overrides, versioned JSON.

Presets are plain instances of ``FitConfig`` (nerfstudio's method_configs idea): a preset is a point in
the accuracy-vs-time trade-off, not a different code path. Every field can be overridden with
``--set key=value``; the resolved config is saved as JSON in the run folder so a run can be resumed and
reproduced exactly.

Each field is declared once, as one annotated line and its docstring: its type and valid range (the vocabulary
below: ``Count``, ``Weight``, ...) are what pydantic validates, for ``--set`` and for a run's config.json alike,
and its docstring is its ``--help-config`` text. A new field is that line, its docstring and, when a checkpoint
made before it must still load, a ``LATER_FIELDS`` entry.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

import pydantic.dataclasses
from pydantic import ConfigDict, Field, TypeAdapter, ValidationError
from pydantic.fields import FieldInfo

from .config_fields import (
    MAX_INT,
    Count,
    Flag,
    Float,
    Int,
    NonNegative,
    NonNegativeInt,
    OneLine,
    Positive,
    Ratio,
    Share,
    Valid,
    kind_of,
    parse_set_value,
    whole_number,
)
from .errors import InputError
from .terms.cli import CLI_MODULE, DEFAULT_PRESET, PRESET_CLIP_FRAMES, PRESET_STEPS
from .terms.versions import SCHEMA_VERSION

#: OpenCV DIS optical-flow presets (``flow_preset``), fastest first; engine/data/flow.py maps each to OpenCV's
#: (``fine``: ``medium`` refined down to full resolution). Named here so the config (and the add-on's tests on a
#: Blender without OpenCV) need no cv2.
FlowPreset = Literal["ultrafast", "fast", "medium", "fine"]
FLOW_PRESETS: tuple[str, ...] = get_args(FlowPreset)

#: The fix for a config.json that is damaged or was edited into something the engine cannot fit with.
CONFIG_FILE_FIX = "restore it, or fit into a new run folder"
#: The smallest working long edge: below it a frame has too few pixels for the gradient and rigidity terms'
#: neighbours and for optical flow.
MIN_LONG_EDGE = 16
#: The largest a loss weight (``w_*``) may be: 200 times the paper's largest (``w_rgb`` 5000). Adam divides each step
#: by the gradient's running size, so no balance of terms needs a larger one; far beyond it a weight overflows
#: float32 (1e308 is Inf there: the first loss is Inf and the fit diverges whatever its learning rate).
MAX_LOSS_WEIGHT = 1e6
#: Bounds no real shot needs to pass, checked before any work: beyond them a value allocates past any machine's
#: memory (a grid's cells grow with the square of a density, a network's weights with the square of a width) or
#: stalls a loop. Each is well above every preset and every value measured in docs/.
#: Texels (cells) per working pixel of an atlas or alpha grid: the presets use 0.25-2.
MAX_DENSITY = 16.0
#: Units of a hidden layer of a network: the presets use 64.
MAX_WIDTH = 4096
#: Hidden layers, grid levels, features per level: the presets use 2-6.
MAX_DEPTH = 32
#: A distance in working pixels (a finite-difference step, a margin, a search, a warp cell): 4K at working size
#: is 3840 pixels wide.
MAX_PIXELS = 4096.0
#: Pixels or samples drawn in one step or one evaluation: the presets draw 4000-20000.
MAX_SAMPLES = 10_000_000
#: A working size's long edge: a plate's, at most 16k (``io.images.MAX_DECODED_BYTES``).
MAX_LONG_EDGE = 16384
#: Growth of a foreground atlas's box beyond the object, as a fraction of its size: the presets use 0.06.
MAX_MARGIN = 10.0
Density = Annotated[Float, Field(gt=0, le=MAX_DENSITY)]
Width = Annotated[Int, Field(ge=1, le=MAX_WIDTH)]
Depth = Annotated[Int, Field(ge=1, le=MAX_DEPTH)]
Pixels = Annotated[Float, Field(gt=0, le=MAX_PIXELS)]
Samples = Annotated[Int, Field(ge=1, le=MAX_SAMPLES)]
#: A loss weight: finite, >= 0 (0 turns its term off) and at most MAX_LOSS_WEIGHT.
Weight = Annotated[Float, Field(ge=0, le=MAX_LOSS_WEIGHT)]


@pydantic.dataclasses.dataclass(config=ConfigDict(use_attribute_docstrings=True, extra="forbid"))
class FitConfig:
    """Everything that decides what a fit computes. Field docstrings are the ``--set`` help."""

    preset: OneLine = DEFAULT_PRESET
    """Name of the preset this config started from (informational)."""
    model: Literal["fast", "paper"] = "fast"
    """Architecture: ``fast`` (multi-resolution grids + small MLPs, the default) or ``paper`` (the paper's MLPs)."""
    steps: Count = 6000
    """Optimisation steps."""
    batch: Samples = 4000
    """Random pixels per step, spread over all frames (the paper uses 10k; the fast model gains more from
    more steps than from bigger batches)."""
    batch_frames: Annotated[NonNegativeInt, Field(le=MAX_SAMPLES)] = 0
    """The clip length ``batch`` is for: a longer clip draws ``batch * frames / batch_frames`` pixels a step, so
    each frame keeps the samples a step gives it (0: ``batch`` whatever the length). Every fast preset: 70, the
    length its steps were measured on; with the 70-frame batch each frame of a 300-frame shot got a quarter of the
    samples, and its background 3.8 dB less (docs/accuracy-vs-time.md, *A long shot at 1080p*)."""
    object_sample_share: Share = 0.0
    """Share of each step's pixels drawn from the masked objects and the ``mask_prior_margin_px`` band around
    them (the rest uniform over the clip): a small object gets enough samples for its mapping to track it."""
    seed: NonNegativeInt = 0
    """Random seed (sampling and initialisation); the same seed gives the same result on CPU."""
    long_edge: Annotated[Int, Field(ge=MIN_LONG_EDGE, le=MAX_LONG_EDGE)] = 768
    """Working resolution: the clip is resized so its long edge has this many pixels (never enlarged)."""

    # --- preprocessing
    flow_preset: FlowPreset = "medium"
    """OpenCV DIS preset for the fit's optical flow: ultrafast | fast | medium | fine (the export follows its own
    ``fine`` flow: ``engine.export.follow_flow.FOLLOW_FLOW_PRESET``)."""
    flow_threshold_px: Positive = 1.0
    """Forward-backward consistency threshold: flow with a larger round-trip error is not used."""

    # --- optimisation
    lr: Positive = 1e-3
    """Adam learning rate of the MLPs (paper model: all parameters, 1e-4)."""
    lr_grid: Positive = 1e-2
    """Adam learning rate of the grid features and per-frame motion (fast model)."""
    lr_final_ratio: Ratio = 0.1
    """The learning rates decay exponentially to this fraction of their start by the last step."""
    lr_mapping_steps: NonNegativeInt = 0
    """The mappings' learning rate reaches ``lr_final_ratio`` of its start at this step and stays there (0: at the
    last step, as the other rates): a long fit whose atlas sharpens keeps its mappings where the flow put them."""

    # --- loss weights (the paper's, App. A and the reference config)
    w_rgb: Weight = 5000.0
    """Reconstruction: squared RGB error."""
    w_gradient: Weight = 1000.0
    """Reconstruction of image gradients (finite differences)."""
    w_sparsity: Weight = 1000.0
    """Sparsity ||(1-alpha) c_f||^2: the foreground atlas holds nothing where the foreground is absent."""
    w_atlas_sparsity: Weight = 10.0
    """Two or more foreground layers (paper Sec. 4.3): l1 on atlas colours at random atlas points replaces
    the sparsity term above (which would blacken what one object hides of another)."""
    atlas_sparsity_samples: Samples = 1024
    """Random atlas points per foreground layer per step for ``w_atlas_sparsity``."""
    w_flow: Weight = 5.0
    """Flow consistency of the mappings (alpha-weighted per layer), in pixels."""
    w_alpha_flow: Weight = 49.0
    """Flow consistency of alpha."""
    long_flow_max_gap: NonNegativeInt = 0
    """Long-range correspondences: flow between frames 2, 4, 8, ... (powers of two up to this) apart, kept where
    it survives the forward-backward check, ties mappings that far apart directly, so small per-pair errors cannot
    add up to a drift over the clip (0 or 1: off; computed with the flow and cached)."""
    long_flow_samples: Samples = 1024
    """Long-range correspondences drawn per step (``object_sample_share`` of them on the objects)."""
    w_long_flow: Weight = 5.0
    """Flow consistency of the mappings over the long-range correspondences (as ``w_flow``: atlas distance in
    pixels, alpha-weighted per layer at the source pixel)."""
    long_flow_stride: Count = 2
    """Long-range correspondences are kept on a pixel grid of this stride (memory: 1/stride^2 of the pixels)."""
    w_rigidity: Weight = 1.0
    """Local rigidity: symmetric Dirichlet energy of the mapping Jacobian (delta = rigidity_delta)."""
    rigidity_delta: Pixels = 1.0
    """Finite-difference step of the local rigidity term, in working pixels."""
    w_global_rigidity_fg: Weight = 5.0
    """Global rigidity of the foreground mapping (bootstrap only)."""
    w_global_rigidity_bg: Weight = 50.0
    """Global rigidity of the background mapping (bootstrap only)."""
    global_rigidity_delta: Pixels = 100.0
    """Finite-difference step of the global rigidity term, in working pixels."""
    global_rigidity_steps: NonNegativeInt = 5000
    """Global rigidity is active for steps < this."""
    w_mask: Weight = 2000.0
    """Mask bootstrap: BCE between alpha and the masks, for steps < bootstrap_steps."""
    bootstrap_steps: NonNegativeInt = 10000
    """Length of the mask bootstrap (paper: 10k of 400k steps)."""
    w_scribble: Weight = 2000.0
    """Scribbles (paper Sec. 4.4, ``fit --scribbles``): -log(alpha_i) at layer i's scribbled pixels, during the
    bootstrap only, like the mask term it refines (same weight: a scribble is as sure as a mask)."""
    scribble_samples: Samples = 512
    """Scribbled pixels drawn per step (they are too sparse to be hit often by the random pixel batch)."""
    scribble_carry: Flag = False
    """The scribble term also at the strokes carried to every frame along the consistent flow (the labels that seed
    each part's motion, ``scribbles.propagate_labels``): the parts' ownership is held on the frames nobody
    scribbled, not only on the two or three that were. Off in every preset: on limbs_jump (three frames of strokes)
    it takes the limb from 0.87 to 0.96 but the body from 0.55 to 0.50 and 2.8 dB of PSNR, the carried labels being
    wrong where the parts cross (docs/bench/experiments.md)."""
    w_mask_prior: Weight = 0.0
    """After the bootstrap, a weak BCE far from the mask boundary keeps alpha from drifting (0 = paper)."""
    mask_prior_margin_px: Annotated[NonNegative, Field(le=MAX_PIXELS)] = 12.0
    """The mask prior ignores pixels closer than this to a mask boundary (masks are coarse hints)."""
    mask_hold_coverage: Share = 0.4
    """After the bootstrap the mask prior holds only the pixels deeper inside a mask than ``mask_prior_margin_px``.
    A thin object (a dog's legs, a bike, a rider) has few such pixels, and its alpha then leaves the parts nothing
    holds. A mask layer whose prior keeps less than this share of its mask pixels as inside keeps the bootstrap's
    mask term (``w_mask``) for the whole fit (term ``mask_hold``; 0 = never). Thick objects (a swan, a car) are
    fitted as before."""
    mask_snap_px: Annotated[NonNegativeInt, Field(le=256)] = 16
    """Loose masks: find, per mask layer, the offset (up to this many working pixels in or out) at which the masks'
    outline meets the clip's strongest edges, and move the masks there before fitting (engine/data/mask_snap.py;
    0 = fit the masks as drawn). A mask drawn 10 px wide otherwise teaches the foreground a ring of background;
    precise masks are left as they are."""

    w_anchor: Weight = 0.0
    """Fast model: squared pixels of a foreground mapping's mean drift (over the layer's mask pixels) from its
    flow-fitted start. A mapping is free to translate as a whole; with a bounded atlas that drift is not
    harmless: the part of the object that slides outside its atlas box lands on empty atlas, which is black (a
    free fit for a dark object), and the rest falls to the background. Only the mean is pinned, so no
    deformation is resisted (docs/engine.md has the drift and alpha IoU with and without it)."""

    # --- paper model
    uv_mapping_scale: Ratio = 0.8
    """Paper model: atlas scale relative to the frame (the mappings are calibrated to scale*identity)."""
    pretrain_iters: NonNegativeInt = 100
    """Paper model: calibration steps of the mappings to (scaled) identity before training."""

    # --- fast model
    mapping_hidden: Width = 64
    """Fast model: width of the residual mapping MLP (no positional encoding: mappings stay smooth)."""
    mapping_time_frames: Annotated[NonNegativeInt, Field(le=MAX_SAMPLES)] = 0
    """Fast model: the clip length over which a mapping's time input spans [-1, 1]; a longer clip's frames keep the
    step in time they have in a clip this long, so a body that turns through a long shot asks the residual MLP for
    no faster change per unit of its input than a short clip does (0: [-1, 1] whatever the length)."""
    mapping_layers: Depth = 3
    """Fast model: hidden layers of the residual mapping MLP."""
    mapping_hidden_fg: Annotated[NonNegativeInt, Field(le=MAX_WIDTH)] = 0
    """Fast model: width of a foreground layer's residual mapping MLP; 0 = ``mapping_hidden``. An object that turns
    in depth shows the mapping new surface every frame: a wider mapping unwraps it onto more of its atlas."""
    atlas_levels: Depth = 6
    """Fast model: resolution levels of each layer's atlas grid (finest has ~1 texel per working pixel)."""
    atlas_features: Depth = 4
    """Fast model: features per atlas grid level."""
    atlas_density: Density = 1.0
    """Fast model: finest atlas texels per working pixel."""
    alpha_levels: Depth = 5
    """Fast model: resolution levels of the alpha grid over (x, y, t)."""
    alpha_features: Depth = 2
    """Fast model: features per alpha grid level."""
    alpha_density: Density = 0.25
    """Fast model: finest alpha grid cells per working pixel."""
    alpha_atlas_density: Annotated[NonNegative, Field(le=MAX_DENSITY)] = 0.0
    """Fast model: an opacity grid in each foreground layer's atlas, at this many finest cells per reference pixel,
    added to the (x, y, t) alpha's logit (0 = none). The (x, y, t) grid learns a thin part (a leg, a bike frame)
    separately in every frame, from the few samples that land on it there; in atlas space every frame's samples of
    that part train the same cells, so an object's shape is learned once and moves with its mapping."""
    alpha_atlas_levels: Depth = 3
    """Fast model: resolution levels of the atlas-space opacity grid (``alpha_atlas_density`` > 0)."""
    decoder_hidden: Width = 64
    """Fast model: width of the colour and alpha decoder MLPs."""
    warp_levels: Annotated[NonNegativeInt, Field(le=MAX_DEPTH)] = 2
    """Fast model: levels of the smooth per-frame warp grid added to each mapping (0 = similarity + MLP only)."""
    warp_foreground: Flag = False
    """Fast model: give foreground mappings a warp grid too (off: it lets an object's mapping slide and
    paint would swim; the background's non-rigid water and foliage are where the warp pays)."""
    warp_cell_px: Pixels = 8.0
    """Fast model: cell size, in working pixels, of the finest warp level (coarser levels double it)."""
    lr_warp: Positive = 0.01
    """Adam learning rate of the warp grid, in pixels per step (every fast preset: 0.05, see ``_fast``)."""
    init_motion: Flag = True
    """Fast model: initialise each layer's per-frame motion from the optical flow (robust similarity fit)."""
    atlas_margin_fg: Annotated[NonNegative, Field(le=MAX_MARGIN)] = 0.06
    """Fast model: a foreground atlas's content rectangle is the object's extent (its masks, mapped by the
    initial motion) grown by this fraction; outside it the atlas is empty. Kept small: empty atlas inside the box
    is black, and a mapping that drifts into it fits dark content for free (``w_anchor`` pins that drift)."""

    # --- scene analysis (engine.data.scene_analysis)
    components: Literal["auto", "all"] = "auto"
    """``auto``: compute only what the scene calls for (a static camera gets a near-identity background
    mapping, a pan/zoom a similarity with a small residual and no warp grid; no foreground or alpha networks
    for a background-only clip; no flow for a single frame; loss terms without anything to act on are not
    evaluated). ``all``: every component on whatever the clip (to compare, or if the analysis is wrong for a
    clip). The decisions and their reasons are written to RUN_DIR/scene.json."""

    atlas_box_full_mask: Flag = False
    """Fast model: a foreground atlas box spans the whole masks (True, every preset) rather than the eroded
    ones the motion is fitted on (False): the erosion keeps the motion fit off unreliable boundary flow, but a
    box drawn from it cuts the rim off small objects (a 30 px object loses 6 px on every side)."""

    # --- bookkeeping
    eval_every: Count = 100
    """Steps between progress lines with PSNR on a fixed pixel sample."""
    eval_pixels: Samples = 20000
    """Size of the fixed pixel sample for the live PSNR."""
    checkpoint_seconds: NonNegative = 120.0
    """Wall-clock seconds between checkpoints (and one at the end and on SIGINT/SIGTERM)."""

    def step_batch(self, frames: int) -> int:
        """Pixels a step draws from a clip of ``frames`` frames (``batch``, grown with a clip longer than
        ``batch_frames``)."""
        if self.batch_frames <= 0 or frames <= self.batch_frames:
            return self.batch
        return math.ceil(self.batch * frames / self.batch_frames)

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


#: Every field as pydantic declared it (its type, its range, its docstring as the description); pydantic sets it on
#: the dataclass it declares, which its type stubs do not say.
_FIELDS: dict[str, FieldInfo] = FitConfig.__pydantic_fields__  # type: ignore[attr-defined]
#: The one validator of every field's value, in a whole config or one field at a time.
_CHECK: TypeAdapter[FitConfig] = TypeAdapter(FitConfig)


#: Every field's valid values, read from its declaration (``--help-config`` shows them; ``check_config`` and
#: ``apply_overrides`` enforce them, for ``--set`` and for a run's config.json alike, before anything is written).
VALID: dict[str, Valid] = {name: Valid.of(info) for name, info in _FIELDS.items()}


#: What ``fit --resume --set`` may change: the schedule (its length and learning rates: a fit that diverged
#: continues from its last good checkpoint with a lower rate) and the bookkeeping. Anything else decides what
#: the fit computes, so a resume that changes it would not continue the same fit: it is refused.
RESUMABLE_FIELDS: tuple[str, ...] = (
    "steps",
    "lr",
    "lr_grid",
    "lr_warp",
    "lr_final_ratio",
    "lr_mapping_steps",
    "eval_every",
    "eval_pixels",
    "checkpoint_seconds",
)
#: Loss phases measured in steps (``engine.loss_terms``: a term is on until or from such a step). One that reaches
#: the fit's last step (``field >= steps``: draft's and balanced's mask bootstrap) is on for the whole fit, and stays
#: so when the fit goes on: ``fit --refine`` moves it to the new last step (let go there, the alpha hands a body that
#: spins or bends to the background: docs/accuracy-vs-time.md), and a resume or a checkpoint may record it so.
PHASE_FIELDS: tuple[str, ...] = ("bootstrap_steps", "global_rigidity_steps")
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
    "mapping_hidden_fg": 0,
    "lr_mapping_steps": 0,
    "batch_frames": 0,
    "mapping_time_frames": 0,
}
#: The learning rates (``fit`` names them when a fit diverges).
LR_FIELDS: tuple[str, ...] = ("lr", "lr_grid", "lr_warp")


def field_kind(name: str) -> str:
    """A field's type as a word: ``int``, ``float``, ``bool`` or ``str`` (a field of choices is a ``str``)."""
    return kind_of(_FIELDS[name])


#: Where a value being checked came from: ``--set`` on the command line (its messages quote the argument).
FROM_SET = "--set"


def _refusal(key: str, value: Any, source: str | Path | None, raw: Any = None) -> InputError:
    """The one line for a value of field ``key`` that its declaration refuses (the adapter from pydantic's
    ``ValidationError``): quoting ``--set key=raw`` when ``source`` is ``FROM_SET``, naming the file when it is a
    path (a run's config.json), and the field alone when None (a config built in code)."""
    kind = field_kind(key)
    want = VALID[key].describe(kind)
    count = whole_number(value) if kind == "int" else None
    if isinstance(count, int) and not isinstance(count, bool) and abs(count) > MAX_INT:
        want += f" (at most {MAX_INT})"
    fix = f"`python -m {CLI_MODULE} fit --help-config` lists every field's range"
    if source == FROM_SET:
        shown = value if raw is None else raw
        return InputError(None, f"--set {key}={shown}: {key} must be {want}", fix)
    if source is None:
        return InputError(None, f"config {key!r} must be {want}, not {value!r}", fix)
    return InputError(source, f"config {key!r} must be {want}, not {value!r}", CONFIG_FILE_FIX)


def check_value(key: str, value: Any, source: str | Path | None = None, raw: Any = None) -> Any:
    """``value`` of field ``key`` as its declaration validates it (returned as its type: a whole float as an int,
    an int as a float), or the one-line ``InputError`` of ``_refusal``."""
    try:
        return getattr(_CHECK.validate_python({key: value}), key)
    except ValidationError:
        raise _refusal(key, value, source, raw) from None


def check_config(cfg: FitConfig, source: str | Path | None = None) -> FitConfig:
    """Every field of ``cfg`` within its type and range (``VALID``), or a one-line ``InputError`` for the first
    that is not (``source``: the file it came from, if any): the one check a config passes before a fit writes
    anything (a field set on an instance after it was made is validated only here)."""
    try:
        _CHECK.validate_python(dataclasses.asdict(cfg))
    except ValidationError as exc:
        key = str(exc.errors()[0]["loc"][0])
        raise _refusal(key, getattr(cfg, key), source) from None
    return cfg


def apply_overrides(cfg: FitConfig, overrides: dict[str, Any], source: str | Path | None = None) -> FitConfig:
    """Return a copy of ``cfg`` with ``overrides`` applied; unknown keys suggest the nearest field, and every
    value is checked against its type and range (``check_value``). ``source``: the file the overrides come from;
    None: ``--set`` strings (``"1e3"``, ``"true"``) or values given in code."""
    values: dict[str, Any] = {}
    for key, raw in overrides.items():
        if key not in _FIELDS:
            near = difflib.get_close_matches(str(key), list(_FIELDS), n=1)
            hint = f"did you mean {near[0]!r}?" if near else f"see `python -m {CLI_MODULE} fit --help-config`"
            raise InputError(source, f"unknown config key {key!r}", hint)
        if source is None and isinstance(raw, str):
            values[key] = check_value(key, parse_set_value(field_kind(key), raw, key), FROM_SET, raw)
        else:
            values[key] = check_value(key, raw, source)
    return dataclasses.replace(cfg, **values)


def whole_fit_phase(values: Mapping[str, Any], name: str) -> bool:
    """Whether the loss phase ``name`` (``PHASE_FIELDS``) of a config's ``values`` lasts the whole fit."""
    return name in PHASE_FIELDS and int(values[name]) >= int(values["steps"])


def same_phases(saved: Mapping[str, Any], new: Mapping[str, Any], name: str) -> bool:
    """Whether two configs' values of ``name`` run the same loss phase: the same step, or both the whole fit (a
    fit continued for more steps keeps a phase it had on from its first step to its last)."""
    return saved[name] == new[name] or (whole_fit_phase(saved, name) and whole_fit_phase(new, name))


def run_on(cfg: FitConfig, last: int, steps: int, keep: Collection[str] = ()) -> FitConfig:
    """``cfg``, whose fit was to end at step ``last``, run on to ``steps``: each loss phase that lasted to ``last`` on
    to the new last step, the others (and those in ``keep``: set by hand) as they were."""
    changes: dict[str, Any] = {"steps": steps}
    changes.update((name, steps) for name in PHASE_FIELDS if name not in keep and last <= getattr(cfg, name) < steps)
    return dataclasses.replace(cfg, **changes)


def resume_changes(saved: FitConfig, new: FitConfig) -> tuple[list[str], list[str]]:
    """The fields ``new`` changes from ``saved``: (those a resume may change, those it may not). A loss phase that
    lasts the whole fit in both (``same_phases``) is a change a resume may make."""
    old, now = dataclasses.asdict(saved), dataclasses.asdict(new)
    changed = [name for name in old if old[name] != now[name]]
    free = [name for name in changed if name in RESUMABLE_FIELDS or same_phases(old, now, name)]
    return free, [name for name in changed if name not in free]


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
        batch_frames=PRESET_CLIP_FRAMES["draft"],
        mapping_time_frames=PRESET_CLIP_FRAMES["draft"],
        bootstrap_steps=PRESET_STEPS["draft"],
        global_rigidity_steps=150,
    ),
    # balanced: the masks are fitted for all of its steps too; let go at step 2000, the alpha gave bodies that spin,
    # bend or turn to the background layer (fg IoU 0.53-0.85 on breakdance, parkour, dance-twirl, camel, cows) and
    # the paint on them with it; held, fg IoU 0.92-1.00 on every clip and the object's paint 0.510 -> 0.548 on the
    # mean (no clip down by more than a seed's spread), at 0.2-3.6 dB of PSNR (docs/accuracy-vs-time.md)
    # balanced: over its 6000 steps a body's mapping slides once the atlas sharpens (paint on a spinning dancer
    # 0.181 at the end against draft's 0.324 at 800 steps); the mappings' rate settled by step 1600 holds it, the
    # atlas, alpha and warp rates decaying over every step (docs/accuracy-vs-time.md, the balanced table)
    "balanced": _fast(
        preset="balanced",
        steps=PRESET_STEPS["balanced"],
        batch_frames=PRESET_CLIP_FRAMES["balanced"],
        mapping_time_frames=PRESET_CLIP_FRAMES["balanced"],
        bootstrap_steps=PRESET_STEPS["balanced"],
        global_rigidity_steps=1000,
        lr_mapping_steps=1600,
    ),
    # final: its long schedule leaves the alpha free for most of the fit after the bootstrap; that long with the
    # balanced bootstrap and prior, the alpha takes reflections and haze into the foreground (the reconstruction
    # gains more than the prior costs: docs/engine.md). The paper's 10000-step bootstrap and a prior ten times
    # stronger make that trade a loss.
    "final": _fast(
        preset="final",
        steps=PRESET_STEPS["final"],
        batch_frames=PRESET_CLIP_FRAMES["final"],
        mapping_time_frames=PRESET_CLIP_FRAMES["final"],
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
    """Every field with its type, default, range and docstring (its pydantic description), for ``--help-config``."""
    default = FitConfig()
    lines = []
    for name, info in _FIELDS.items():
        kind = field_kind(name)
        valid = VALID[name].describe(kind)
        resumable = ", resumable" if name in RESUMABLE_FIELDS else ""
        # the description is the docstring dedented: its continuation lines indented as the source has them
        doc = (info.description or "").replace("\n", "\n    ")
        lines.append(f"  {name} ({kind}, default {getattr(default, name)!r}, {valid}{resumable}): {doc}")
    resumable_note = (
        f"resumable: `fit --resume --set` may change only {', '.join(RESUMABLE_FIELDS)}; "
        "any other field starts a new fit (a new --out, or --refit)"
    )
    return "\n".join([*lines, "", resumable_note])


__all__ = [
    "LATER_FIELDS",
    "LR_FIELDS",
    "PHASE_FIELDS",
    "PRESETS",
    "RESUMABLE_FIELDS",
    "START_FIELDS",
    "VALID",
    "FitConfig",
    "apply_overrides",
    "check_config",
    "check_value",
    "config_help",
    "field_kind",
    "parse_set_args",
    "preset_config",
    "resume_changes",
    "run_on",
    "same_phases",
    "whole_fit_phase",
]
