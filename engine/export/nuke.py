"""A Nuke script of an export's edit, from its manifest alone (as the add-on builds Blender's compositor tree).

Per layer: the layer's UV pass copied into rgba (u, v and the coverage into red, green and alpha: a Copy node, so
the pass files need no STMap copy, ``export --stmap``), an STMap of the layer's edit image (premultiplied), masked by
the coverage (Merge mask: ``Z * P``); the layers summed (Merge plus) and put
over the plate with one premultiplied Merge over: ``plate * (1 - sum Z_i a_i) + sum Z_i P_i``, the paper's edit
equation as ``engine.edit.equations`` computes it. The frame range, fps and format are the export's. The Root sets
OCIO colour management with ONE config, the export's (or a studio's, ``engine nuke --ocio-config``), and every
``colorspace`` knob is a name of that config (``script_colour``), so no Read depends on another config's names.

The test suite has no Nuke to run it in: it parses the script back (node classes, knobs, the input wiring, that
every file it reads exists and every channel it names is in the pass files) and evaluates a model of its nodes.
Paths are relative to the script's folder (the Root's project directory is set to it), so the export folder can
move with its run folder.

Nothing from the manifest reaches Nuke's Tcl as code: knob values are written quoted with every Tcl special
character escaped (``quote``), the stack variables are named by the layer's index, the header comment holds only
plain names, and a path a Read would misread (a frame token, Tcl Nuke evaluates in file names, bytes that are not
UTF-8) is refused in one line (``file_knob_path``).

Nuke's EXR reader names channels by the rule of its NDK example ``ExrChannelNameToNuke``: split at dots (three
parts at most), drop leading digits, turn other non-alphanumerics into "_", join all but the last part with "_" as
the layer, and rename R/G/B/A (and r, Red, RED ...) to red/green/blue/alpha. ``nuke_channel_name`` is that rule.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import contract as C
from ..errors import InputError
from ..terms.manifest import is_layer_name
from ..terms.versions import ENGINE_VERSION

#: The script's format line: Nuke 13 and later load it (the nodes used are older than that).
NUKE_VERSION = "13.0 v1"
#: STMap's filters (its ``filter`` knob). Impulse is nearest-texel sampling: it matches `engine render --filter
#: nearest` exactly; Cubic is Nuke's default.
STMAP_FILTERS: tuple[str, ...] = ("Cubic", "Impulse", "Keys", "Simon", "Rifman", "Mitchell", "Parzen", "Notch")
DEFAULT_FILTER = "Cubic"
#: The Root's project directory: the script's own folder, so the relative paths below are relative to it.
SCRIPT_DIRECTORY = "[python {nuke.script_directory()}]"
#: The Root's colour knobs: OCIO colour management with the config named by its path (or an ``ocio://`` URI, which
#: Nuke hands to OCIO as it is), so every Read's ``colorspace`` is a name of that one config.
OCIO_MANAGEMENT = "OCIO"
OCIO_CUSTOM = "custom"
#: ``engine nuke``'s option naming a studio's OCIO config to write the script in.
OCIO_CONFIG_ARG = "--ocio-config"
#: Where the pass files' frame number stands in the manifest's pattern (``atlas.{frame:04d}.exr``).
_PATTERN_FRAME = re.compile(r"\{frame(?::0?(\d*)d)?\}")
#: Node names carry this prefix, so the script's nodes are recognisable once pasted into a comp.
PREFIX = "NA_"
#: Nuke's rgba channels, in order: a layer's u, v and coverage are copied into red, green and alpha.
NUKE_RGBA: tuple[str, ...] = ("rgba.red", "rgba.green", "rgba.blue", "rgba.alpha")
#: Node graph spacing (pixels) between the layers' columns and the rows of a column.
COLUMN = 180
ROW = 60
_RGBA = {"R": "red", "G": "green", "B": "blue", "A": "alpha"}
_RGBA_SPELLINGS = {
    spelling: name for c, name in _RGBA.items() for spelling in (c, c.lower(), name.title(), name.upper())
}
#: A knob value written as it is (one plain word); anything else is quoted and escaped.
_BARE = re.compile(r"[A-Za-z0-9_./%:+-]+")
#: Characters escaped with a backslash inside a quoted knob value: Tcl's substitutions, word and command ends.
_TCL_SPECIAL = frozenset('\\"[]${};')
#: Control characters Tcl writes as named escapes; the other ones are written as ``\uXXXX``.
_TCL_NAMED_ESCAPES = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}
#: Characters a Read's file knob gives a meaning, with no escape for them: runs of ``#`` and printf ``%d``,
#: ``%0Nd`` (``%V``, ``%v``: the view) are frame tokens; ``[...]``, ``$name`` and ``\`` are Tcl, which Nuke
#: evaluates in a file name each time it reads one. A path holding one is refused, never rewritten.
FILE_KNOB_SPECIAL = "#%[]$\\"
#: The fix of a path a Read cannot hold: the folder's name, or where the script is (its paths are relative to it).
FILE_KNOB_FIX = (
    "rename the folder or file (or write the script with `engine nuke --out` in a folder from which the path does not "
    "pass through it)"
)
#: What header comments may hold: a newline or a trailing backslash would end or extend a Tcl comment.
_COMMENT_UNSAFE = re.compile(r"[^A-Za-z0-9_ ,.:;'()=+*/-]")


class NukeScriptError(ValueError):
    """An export the script cannot be made for (one line: what and the fix)."""


def nuke_channel_name(exr_channel: str, views: Iterable[str] = ()) -> str:
    """The name Nuke's EXR reader gives the EXR channel ``exr_channel`` (the NDK's ExrChannelNameToNuke rule)."""
    parts = exr_channel.split(".", 2)  # at most three parts: the last keeps any further dots
    cleaned = [re.sub(r"[^A-Za-z0-9]", "_", p.lstrip("0123456789")) for p in parts]
    cleaned = [p for p in cleaned if p]
    if not cleaned:
        return "unnamed"
    views = set(views)
    layer = "_".join(p for p in cleaned[:-1] if p not in views)
    chan = cleaned[-1]
    if layer == "Ci":  # RenderMan's primary layer is Nuke's main layer
        layer = ""
    chan = _RGBA_SPELLINGS.get(chan, chan)
    return f"{layer}.{chan}" if layer else chan


def sequence_pattern(files: list[str], numbers: list[int]) -> str:
    """The printf pattern (``plate.%04d.exr``) that names each of ``files`` with its frame number; raises
    NukeScriptError when the files are not one numbered sequence (Nuke reads a sequence through one pattern)."""
    heads, widths, padded = set(), set(), False
    for path, number in zip(files, numbers, strict=True):
        stem, ext = os.path.splitext(path.replace(os.sep, "/"))
        found = list(re.finditer(r"\d+", os.path.basename(stem)))
        if not found or int(found[-1].group()) != number:
            raise NukeScriptError(
                f"plate frame {os.path.basename(path)!r} is not named with its frame number {number} — Nuke reads "
                "a plate as one numbered sequence (name.####.ext): rename the frames and fit again, or Read it by hand"
            )
        digits = found[-1]
        offset = len(stem) - len(os.path.basename(stem))
        heads.add((stem[: offset + digits.start()], stem[offset + digits.end() :] + ext))
        widths.add(len(digits.group()))
        padded = padded or digits.group().startswith("0")
    if len(heads) != 1 or (len(widths) > 1 and padded):
        raise NukeScriptError(
            "the plate's frames are not one numbered sequence (their names or padding differ) — Nuke reads a "
            "plate through one pattern: rename the frames name.####.ext and fit again, or Read the plate by hand"
        )
    head, tail = heads.pop()
    return f"{head}{f'%0{widths.pop()}d' if len(widths) == 1 else '%d'}{tail}"


@dataclass(frozen=True)
class ScriptColour:
    """The colour of a script: one OCIO config and the names in it that the Reads and the Root use."""

    config: str  # the config's path or ``ocio://`` URI, set on the Root
    plate: str  # the plate's colour space
    srgb: str  # PNG edit layers: sRGB-encoded Rec.709
    linear: str  # float edit layers, and the Root's working space: scene-linear Rec.709 (Blender's, the engine's)


def script_colour(clip: dict[str, Any], ocio_config: str | None = None) -> ScriptColour:
    """The names a script of ``clip`` (a manifest's) uses: those of the config the export was made in, or of
    ``ocio_config`` (a studio's), which must know the plate's colour space (a name, an alias or a role). Raises
    InputError naming the config when it cannot be loaded or lacks a space."""
    from ..io.colour import SCENE_LINEAR, SRGB, load_config, recorded_space, resolve, role_space

    plate, config = recorded_space(clip["colorspace"], clip.get("colour_config"))
    if ocio_config is not None and not ocio_config.isprintable():  # it would be written into the script as it is
        raise InputError(
            ocio_config.strip(), f"{OCIO_CONFIG_ARG} holds a newline or a control character", "give the path alone"
        )
    if ocio_config is not None and ocio_config != config:
        if not ocio_config.startswith("ocio://") and not os.path.isfile(ocio_config):
            fix = f"give {OCIO_CONFIG_ARG} the path of an OCIO config file (or an ocio:// URI)"
            raise InputError(ocio_config, "OCIO config does not exist", fix)
        load_config(ocio_config)
        try:
            plate, config = resolve(plate, ocio_config), ocio_config
        except InputError as exc:
            same = _same_role(plate, config, ocio_config)
            if same is None:
                fix = f"give {OCIO_CONFIG_ARG} a config that has it, or leave it out to use the export's ({config})"
                raise InputError(ocio_config, f"has no colour space {plate!r} (the plate's)", fix) from exc
            plate, config = same, ocio_config
    return ScriptColour(config, plate, role_space(SRGB, config), role_space(SCENE_LINEAR, config))


def _same_role(space: str, config: str, other: str) -> str | None:
    """``other``'s space for the fixed role (sRGB, scene-linear Rec.709, raw) that ``space`` plays in ``config``
    (configs name them differently: "sRGB Encoded Rec.709 (sRGB)", "sRGB"); None when it plays none, or ``config``
    cannot be loaded here."""
    from ..io.colour import RAW, SCENE_LINEAR, SRGB, role_space

    for role in (SRGB, SCENE_LINEAR, RAW):
        try:
            if role_space(role, config) == space:
                return role_space(role, other)
        except InputError:
            return None
    return None


def pass_sequence_pattern(pattern: str) -> str:
    """The printf pattern of a manifest's pass pattern (``atlas.{frame:04d}.exr`` -> ``atlas.%04d.exr``), which is
    how a Read names a sequence; raises NukeScriptError for a pattern the engine does not write."""
    found = _PATTERN_FRAME.findall(pattern)
    if len(found) != 1 or "%" in pattern or "#" in pattern:
        raise NukeScriptError(f"the manifest's pass pattern {pattern!r} is not one the engine writes")
    width = found[0]
    return _PATTERN_FRAME.sub(f"%0{width}d" if width and int(width) > 1 else "%d", pattern)


@dataclass
class Node:
    """One node of the script: its class, its knobs in order, and the stack commands written before it."""

    cls: str
    knobs: list[tuple[str, str]]
    before: list[str] = field(default_factory=list)
    after: list[str] = field(default_factory=list)


def quote(value: str) -> str:
    """A knob value as the script writes it: bare when it is one plain word, else in double quotes with every Tcl
    special character backslash-escaped and control characters as escapes, so Tcl reads back exactly ``value``
    (no substitution, no second command, no line break inside the node's body)."""
    if _BARE.fullmatch(value):
        return value
    out = []
    for ch in value:
        if ch in _TCL_SPECIAL:
            out.append("\\" + ch)
        elif ch in _TCL_NAMED_ESCAPES:
            out.append(_TCL_NAMED_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        elif 0xD800 <= ord(ch) <= 0xDFFF:  # a byte that was not UTF-8 (surrogateescape): no text can hold it
            raise NukeScriptError(f"the value {value!r} holds bytes that are not UTF-8 — rename what it names")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def file_knob_path(path: str, what: str, knob: str | None = None) -> str:
    """The file knob ``knob`` (default: ``path`` itself; else ``path``'s sequence with the frame token written in)
    after checking ``path``, one concrete file: raises NukeScriptError (what and the fix) when Nuke would read part
    of it as a frame token or as Tcl, or when it is not UTF-8 text. A relative knob starting with ``~`` gets ``./``
    (Nuke expands a leading ``~`` to a home folder)."""
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        raise NukeScriptError(
            f"the {what} path {path!r} holds bytes that are not UTF-8, which a Nuke script cannot name — "
            + FILE_KNOB_FIX
        ) from None
    special = "".join(sorted({ch for ch in path if ch in FILE_KNOB_SPECIAL}))
    if special:
        raise NukeScriptError(
            f"the {what} path {path!r} holds {special!r}, which a Nuke Read takes as a frame token or as Tcl (it "
            f"has no escape for them) — {FILE_KNOB_FIX}"
        )
    knob = path if knob is None else knob
    return f"./{knob}" if knob.startswith("~") else knob


def _comment(text: str) -> str:
    """One Tcl comment line of ``text``: anything that could end it (a newline) or extend it (a backslash) is
    replaced, so the comment stays a comment."""
    return "# " + _COMMENT_UNSAFE.sub("_", text)


def _format(size: list[int], pixel_aspect: float = 1.0) -> str:
    w, h = size
    return f"{w} {h} 0 0 {w} {h} {pixel_aspect:g} {PREFIX}{w}x{h}"


def _read(name: str, file: str, knobs: list[tuple[str, str]], x: int, y: int) -> Node:
    return Node("Read", [("inputs", "0"), ("file", file), *knobs, ("name", name), ("xpos", str(x)), ("ypos", str(y))])


def nuke_script(
    manifest: dict[str, Any],
    manifest_path: str,
    relocate: Callable[[str], str] = lambda path: path,
    filter: str = DEFAULT_FILTER,
    ocio_config: str | None = None,
) -> str:
    """The script's text for a validated manifest at ``manifest_path`` (which says where an edit layer's float twin
    would be). ``relocate`` turns a manifest path (relative to the manifest's folder) into the path the script
    writes (relative to the script's folder, "/" separated): the identity for a script next to the manifest.
    ``ocio_config``: the OCIO config the script names its colour spaces in (default: the export's)."""
    if filter not in STMAP_FILTERS:
        raise NukeScriptError(f"STMap filter {filter!r} is not one of {', '.join(STMAP_FILTERS)}")
    layers = manifest["layers"]
    for layer in layers:  # load_manifest refuses them too; a manifest given as a dict may not have been loaded
        if not is_layer_name(layer["name"]):
            raise NukeScriptError(
                f"layer name {layer['name']!r} is not a plain name (letters, digits and _) — export the run again"
            )
    clip, passes = manifest["clip"], manifest["passes"]
    frames = passes["frames"]
    first, last = min(frames), max(frames)
    fmt = _format(clip["resolution"], float(clip.get("pixel_aspect", 1.0)))
    colour = script_colour(clip, ocio_config)
    nodes = [_root(first, last, clip["fps"], fmt, colour)]
    # the pass files are named by the manifest's pattern (``Manifest.pass_path``), padded as the plate's frames
    pass_pattern = pass_sequence_pattern(passes["pattern"])
    pass_file = file_knob_path(
        relocate(f"{passes['dir']}/{passes['pattern'].format(frame=first)}"),
        "pass file",
        relocate(f"{passes['dir']}/{pass_pattern}"),
    )
    range_knobs = [("first", str(first)), ("last", str(last)), ("origfirst", str(first)), ("origlast", str(last))]
    passes_read = _read(
        f"{PREFIX}Passes", pass_file, [("format", fmt), *range_knobs, ("origset", "true"), ("raw", "true")], 0, 0
    )
    passes_read.after.append(f"set {PREFIX}passes [stack 0]")
    nodes.append(passes_read)
    for i, layer in enumerate(layers):
        nodes.extend(
            _layer_nodes(i, layer, uv_channels(passes["exr_layer"], layer), manifest_path, relocate, filter, colour)
        )
    nodes.append(_plate_read(clip, relocate, fmt, colour.plate, x=-COLUMN, y=ROW * 6))
    over = [("inputs", "2"), ("operation", "over"), ("name", f"{PREFIX}Over_plate")]
    nodes.append(Node("Merge2", [*over, ("xpos", "0"), ("ypos", str(ROW * 7))]))
    return _text(nodes, manifest)


def _root(first: int, last: int, fps: float | None, fmt: str, colour: ScriptColour) -> Node:
    knobs = [("inputs", "0"), ("project_directory", SCRIPT_DIRECTORY), ("frame", str(first))]
    knobs += [("first_frame", str(first)), ("last_frame", str(last)), ("lock_range", "true")]
    if fps:
        knobs.append(("fps", f"{fps:.6g}"))
    knobs.append(("format", fmt))
    # one config for every Read: the export's (or the studio's), working in Blender's and the engine's linear space
    config = file_knob_path(colour.config, "OCIO config")
    knobs += [("colorManagement", OCIO_MANAGEMENT), ("OCIO_config", OCIO_CUSTOM), ("customOCIOConfigPath", config)]
    knobs.append(("workingSpaceLUT", colour.linear))
    return Node("Root", knobs)


def uv_channels(exr_layer: str, layer: dict[str, Any]) -> list[str]:
    """The Nuke names of a layer's u, v and coverage channels (its UV pass, ``uv_channels`` in the manifest's order),
    e.g. ``Atlas_UVForeground.U``; a name that is not plain letters, digits, ``_`` and one ``.`` is refused (it is
    written into the script's ``add_layer`` line)."""
    names = [nuke_channel_name(f"{exr_layer}.{layer['uv_pass']}.{c}") for c in layer["uv_channels"]]
    for name in names:
        if not re.fullmatch(r"[A-Za-z0-9_]+\.[A-Za-z0-9_]+", name):
            raise NukeScriptError(f"UV channel {name!r} is not a plain Nuke channel name — export the run again")
    return names


def _layer_nodes(
    i: int,
    layer: dict[str, Any],
    uv: list[str],
    manifest_path: str,
    relocate: Callable[[str], str],
    filter: str,
    colour: ScriptColour,
) -> list[Node]:
    """Copy (the UV pass into rgba) -> STMap -> Merge (mask) of one layer; from the second layer on, a Merge (plus)
    into the sum. ``uv``: its u, v and coverage channels as Nuke names them (``uv_channels``).

    Seven parameters: the layer, its place and what the whole script shares (paths, filter, colours)."""
    name, x = layer["name"], i * COLUMN
    declare = f"add_layer {{{uv[0].split('.')[0]} {' '.join(uv)}}}"
    pushes = [f"push ${PREFIX}passes"] * (2 if i else 1)  # Copy's two inputs are both the pass file
    copy = [("inputs", "2")]
    for k, (src, dst) in enumerate(zip(uv, (NUKE_RGBA[0], NUKE_RGBA[1], NUKE_RGBA[3]), strict=True)):
        copy += [(f"from{k}", src), (f"to{k}", dst)]
    uv_copy = Node("Copy", [*copy, ("name", f"{PREFIX}UV_{name}")], before=[declare, *pushes])
    uv_copy.knobs += [("xpos", str(x)), ("ypos", str(ROW))]
    # the Tcl variable is named by the index: a name never becomes code, whatever it holds
    uv_copy.after += [f"set {PREFIX}st_{i} [stack 0]", f"push ${PREFIX}st_{i}"]
    # the float twin when it exists, as the engine and Blender read it (the script is written for what exists now)
    twin = C.float_edit_layer(layer["edit_layer"])
    is_float = os.path.exists(C.resolve_manifest_path(manifest_path, twin))
    edit = twin if is_float else layer["edit_layer"]
    knobs = [("colorspace", colour.linear)] if is_float else [("colorspace", colour.srgb), ("premultiplied", "false")]
    edit_file = file_knob_path(relocate(edit), f"{name} edit layer")
    nodes = [uv_copy, _read(f"{PREFIX}Edit_{name}", edit_file, knobs, x + COLUMN // 2, ROW)]
    if not is_float:  # a PNG edit layer is straight alpha: premultiply after the sRGB decode, as Blender does
        nodes.append(Node("Premult", [("name", f"{PREFIX}Premult_{name}"), ("xpos", str(x + COLUMN // 2))]))
        nodes[-1].knobs.append(("ypos", str(ROW * 2)))
    stmap = [
        ("inputs", "2"),
        ("channels", "rgba"),
        ("uv", "rgb"),
        ("filter", filter),
        ("name", f"{PREFIX}STMap_{name}"),
    ]
    nodes.append(Node("STMap", [*stmap, ("xpos", str(x)), ("ypos", str(ROW * 3))]))
    mask = [("inputs", "2"), ("operation", "mask"), ("name", f"{PREFIX}Coverage_{name}")]
    nodes.append(Node("Merge2", [*mask, ("xpos", str(x)), ("ypos", str(ROW * 4))]))
    if i:
        plus = [("inputs", "2"), ("operation", "plus"), ("name", f"{PREFIX}Sum_{name}")]
        nodes.append(Node("Merge2", [*plus, ("xpos", "0"), ("ypos", str(ROW * 5 + i))]))
    return nodes


def _plate_read(
    clip: dict[str, Any], relocate: Callable[[str], str], fmt: str, colorspace: str, x: int, y: int
) -> Node:
    numbers = clip["frame_numbers"]
    first, last = numbers[0], numbers[-1]
    colour = [("colorspace", colorspace)]
    if clip["kind"] == C.CLIP_KINDS[0]:
        for frame_file in clip["frame_files"]:  # every frame: the token replaces digits that differ between them
            file_knob_path(relocate(frame_file), "plate frame")
        file = file_knob_path(
            relocate(clip["frame_files"][0]), "plate", relocate(sequence_pattern(clip["frame_files"], numbers))
        )
        frame_knobs: list[tuple[str, str]] = []
        file_first, file_last = first, last
    else:  # a movie: Nuke numbers its frames from 1, the manifest from its start frame (0 unless fit --start-frame)
        file = file_knob_path(relocate(clip["source"]), "plate movie")
        shift = 1 - int(clip.get("start_frame", 0))
        frame_knobs = [("frame_mode", "expression"), ("frame", f"frame{shift:+d}")]
        file_first, file_last = first + shift, last + shift
    rng = [("first", str(file_first)), ("last", str(file_last)), ("origfirst", str(file_first))]
    rng += [("origlast", str(file_last)), ("origset", "true")]
    return _read(f"{PREFIX}Plate", file, [("format", fmt), *rng, *frame_knobs, *colour], x, y)


def _text(nodes: list[Node], manifest: dict[str, Any]) -> str:
    names = ", ".join(layer["name"] for layer in manifest["layers"])
    lines = [
        "#!" + _comment(f"written by neural-atlas {ENGINE_VERSION} from an export's manifest (layers: {names})")[1:],
        _comment("the paper's edit: plate * (1 - sum Z_i a_i) + sum Z_i P_i; structure-tested, not run in Nuke"),
        f"version {NUKE_VERSION}",
    ]
    for node in nodes:
        lines.extend(node.before)
        lines.append(f"{node.cls} {{")
        lines.extend(f" {knob} {quote(value)}" for knob, value in node.knobs)
        lines.append("}")
        lines.extend(node.after)
    return "\n".join(lines) + "\n"


def relocator(manifest_path: str, script_path: str) -> Callable[[str], str]:
    """``relocate`` for a script at ``script_path``: a manifest path made relative to the script's folder ("/"
    separated), or absolute where no relative path exists (another Windows drive)."""
    script_dir = os.path.dirname(os.path.abspath(script_path))

    def relocate(path: str) -> str:
        absolute = C.resolve_manifest_path(manifest_path, path)
        try:
            return os.path.relpath(absolute, os.path.realpath(script_dir)).replace(os.sep, "/")
        except ValueError:
            return absolute.replace(os.sep, "/")

    return relocate


def write_nuke_script(
    manifest_path: str | os.PathLike[str],
    out: str | os.PathLike[str],
    filter: str = DEFAULT_FILTER,
    ocio_config: str | None = None,
) -> Path:
    """``engine nuke``: write the script of the export at ``manifest_path`` to ``out`` (a new file: an existing one,
    maybe the artist's comp, is never overwritten), its colour spaces named in ``ocio_config`` (default: the
    export's config); returns its path. Errors are one line naming the file and the fix.
    """
    from ..io.atomic import atomic_write_text
    from .manifest import Manifest

    manifest = Manifest(os.fspath(manifest_path))
    target = Path(out).resolve()
    if target.suffix.lower() != ".nk":
        raise InputError(target, "a Nuke script's name ends in .nk", "pass --out FILE.nk")
    if target.exists():
        raise InputError(target, "exists (a Nuke script may hold the artist's work)", "choose a new --out FILE.nk")
    try:
        relocate = relocator(str(manifest.path), str(target))
        text = nuke_script(manifest.data, str(manifest.path), relocate, filter, ocio_config)
    except NukeScriptError as exc:
        problem, _, fix = str(exc).partition(" — ")
        raise InputError(manifest.path, problem, fix or "export the run again") from None
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(target, text)
    return target


__all__ = [
    "DEFAULT_FILTER",
    "FILE_KNOB_SPECIAL",
    "STMAP_FILTERS",
    "NukeScriptError",
    "ScriptColour",
    "file_knob_path",
    "nuke_channel_name",
    "nuke_script",
    "pass_sequence_pattern",
    "quote",
    "relocator",
    "script_colour",
    "sequence_pattern",
    "uv_channels",
    "write_nuke_script",
]
