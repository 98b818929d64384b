"""A Nuke script read back, for tests (Nuke itself cannot run here): its nodes, their knobs and their inputs, and a
numpy model of the few nodes the engine writes, to check that the wiring computes the edit equation.

The .nk format is a stack machine: a node takes its inputs from the top of the stack (``inputs N``, 1 by default;
input 0 is the topmost) and is pushed; ``set VAR [stack 0]`` names the top, ``push $VAR`` pushes it again. Knob
values are one word or a quoted string with backslash escapes.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import OpenImageIO as oiio

from engine.export.nuke import nuke_channel_name
from engine.io.colour import convert


@dataclass(eq=False)
class NkNode:
    cls: str
    knobs: dict[str, str]
    inputs: list[NkNode] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.knobs.get("name", self.cls)


@dataclass
class NkScript:
    version: str
    root: dict[str, str]
    nodes: list[NkNode]
    leftover: list[NkNode]  # the stack at the end: the last node on top
    layers: dict[str, list[str]] = field(default_factory=dict)  # the add_layer lines: layer -> its channels

    def node(self, name: str) -> NkNode:
        (found,) = [n for n in self.nodes if n.name == name]
        return found


def unquote(value: str) -> str:
    if not value.startswith('"'):
        assert " " not in value, value
        return value
    assert value.endswith('"') and len(value) >= 2, value
    body = value[1:-1]
    out, i = [], 0
    while i < len(body):
        if body[i] == "\\":
            out.append(body[i + 1])
            i += 2
        else:
            assert body[i] != '"', value
            out.append(body[i])
            i += 1
    return "".join(out)


def parse(text: str) -> NkScript:
    version, root, nodes, stack, names, layers = "", {}, [], [], {}, {}
    lines = iter(text.splitlines())
    for line in lines:
        if not line.strip() or line.startswith("#"):
            continue
        if line.startswith("version "):
            version = line.split(" ", 1)[1]
        elif m := re.fullmatch(r"set (\w+) \[stack 0\]", line):
            names[m.group(1)] = stack[-1]
        elif line.startswith("add_layer {"):
            layer, *channels = line[len("add_layer {") : -1].split(" ")
            assert line.endswith("}") and all(c.split(".")[0] == layer for c in channels), line
            layers[layer] = channels
        elif m := re.fullmatch(r"push \$(\w+)", line):
            stack.append(names[m.group(1)])
        elif m := re.fullmatch(r"(\w+) \{", line):
            knobs = {}
            for body in lines:
                if body == "}":
                    break
                key, _, value = body.strip().partition(" ")
                assert key not in knobs, f"knob {key} twice"
                knobs[key] = unquote(value)
            if m.group(1) == "Root":
                root = knobs
                continue
            count = int(knobs.get("inputs", "1"))
            node = NkNode(m.group(1), knobs, [stack.pop() for _ in range(count)])
            stack.append(node)
            nodes.append(node)
        else:
            raise AssertionError(f"not a line of a Nuke script: {line!r}")
    return NkScript(version, root, nodes, stack, layers)


# --- the nodes' arithmetic, as Nuke's documentation gives it (images: nuke channel name -> [H, W], row 0 at top) ---
RGBA = ("rgba.red", "rgba.green", "rgba.blue", "rgba.alpha")


def file_for(read: NkNode, script_dir: Path, frame: int) -> Path:
    name = read.knobs["file"]
    if "%" in name:
        name = name % frame
    return script_dir / name if not os.path.isabs(name) else Path(name)


def read_channels(path: Path) -> dict[str, np.ndarray]:
    """Every channel of an image file under the name Nuke gives it (a main-layer channel as rgba.<name>)."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)  # a PNG's colour as stored (straight), as Nuke's Read gives it
    inp = oiio.ImageInput.open(str(path), config)
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
    inp.close()
    out = {}
    for i, exr_name in enumerate(spec.channelnames):
        nuke = nuke_channel_name(exr_name)
        out[nuke if "." in nuke else f"rgba.{nuke}"] = np.asarray(pixels[..., i], np.float32)
    return out


def evaluate(node: NkNode, script_dir: Path, frame: int, root: dict[str, str] | None = None) -> dict[str, np.ndarray]:
    """The node's image at ``frame``; a Read that is not raw converts from its ``colorspace`` to the Root's working
    space (``root``: its knobs) in the config the Root declares, by OCIO as Nuke does (and as `render` decodes)."""
    cls, k = node.cls, node.knobs
    if cls == "Read":
        chans = read_channels(file_for(node, script_dir, frame))
        if k.get("raw") != "true":
            assert root is not None, "a Read with a colour space needs the Root's config"
            rgb = np.stack([chans[c] for c in RGBA[:3]], -1)
            rgb = convert(rgb, k["colorspace"], root["workingSpaceLUT"], root["customOCIOConfigPath"])
            for i, c in enumerate(RGBA[:3]):
                chans[c] = np.ascontiguousarray(rgb[..., i])
        return chans
    ins = [evaluate(i, script_dir, frame, root) for i in node.inputs]
    shape = next(iter(ins[0].values())).shape
    zero = np.zeros(shape, np.float32)
    if cls == "Shuffle":
        layer = k["in"]
        return {out: ins[0].get(f"{layer}.{out.split('.')[1]}", zero) for out in RGBA}
    if cls == "Copy":  # input 0 is B (passed through), input 1 is A: channel from<k> of A into to<k>
        b, a = ins[0], ins[1]
        out = dict(b)
        for key in k:
            if key.startswith("from"):
                out[k["to" + key[4:]]] = a[k[key]]
        return out
    if cls == "Premult":
        img = dict(ins[0])
        for c in RGBA[:3]:
            img[c] = img[c] * img["rgba.alpha"]
        return img
    if cls == "STMap":
        assert k["filter"] == "Impulse" and k["uv"] == "rgb" and k["channels"] == "rgba"
        src, stmap = ins[0], ins[1]
        th, tw = src["rgba.red"].shape
        u, v = stmap["rgba.red"], stmap["rgba.green"]
        inside = (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
        col = np.clip(np.floor(u * np.float32(tw)), 0, tw - 1).astype(int)
        row = th - 1 - np.clip(np.floor(v * np.float32(th)), 0, th - 1).astype(int)
        return {c: np.where(inside, src.get(c, np.zeros((th, tw), np.float32))[row, col], 0.0) for c in RGBA}
    if cls == "Merge2":
        b, a = ins[0], ins[1]  # input 0 is B, input 1 is A
        op = k["operation"]
        if op == "mask":
            return {c: b[c] * a["rgba.alpha"] for c in RGBA}
        if op == "plus":
            return {c: a[c] + b[c] for c in RGBA}
        if op == "over":
            return {c: a.get(c, zero) + b.get(c, zero) * (1.0 - a["rgba.alpha"]) for c in RGBA}
    raise AssertionError(f"no model of {cls} {k.get('operation', '')}")


def pyocio() -> Any:
    """PyOpenColorIO, the OCIO library Nuke and Blender load configs with: Blender ships it beside bpy (in the
    test venv); None where no bpy is installed."""
    import importlib.util
    import sys

    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        return None
    found = sorted(Path(spec.origin).parent.glob("*/python/lib/python3.*/site-packages/PyOpenColorIO"))
    if not found:
        return None
    if str(found[-1].parent) not in sys.path:
        sys.path.append(str(found[-1].parent))
    import PyOpenColorIO

    return PyOpenColorIO


def colour_knobs(nk: NkScript) -> dict[str, str]:
    """Every colour-space name the script gives: each Read's ``colorspace`` and the Root's working space, by where."""
    found = {f"{n.name}.colorspace": n.knobs["colorspace"] for n in nk.nodes if "colorspace" in n.knobs}
    found["Root.workingSpaceLUT"] = nk.root["workingSpaceLUT"]
    return found
