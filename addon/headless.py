"""Headless job: an export -> a .blend with the add-on's compositor tree (+ edit layers) -> the edited clip.

Runs inside Blender, never inside the engine (the engine does not import bpy; ``engine/demo.py`` starts this
as a subprocess). Either with the real application or with a Python that has the ``bpy`` module:

    blender -b --factory-startup --python-exit-code 1 -P addon/headless.py -- MANIFEST --blend OUT.blend \\
        [--edit Foreground=paint.png ...] [--render DIR] [--filter bilinear|nearest] [--report OUT.json]
    .venv/bin/python addon/headless.py -- MANIFEST --blend OUT.blend ...

It loads this checkout as the add-on package (no installed extension needed), imports the manifest exactly as
**Import Atlas** does (the given edit images become the layers' edit layers), saves the .blend, and renders
every exported frame through the compositor as scene-linear float EXR ``DIR/edit.1001.exr`` .., named as
``engine render`` names its frames (the plate's frame number padded as the plate's files are; five digits for a
movie). ``--report`` writes what was done (Blender version, filter, files) as JSON for the caller.

Exit: 0 on success; 2 with a one-line ``error: ...`` on bad input. On bpy 4.5 a script that ends with classes
still registered can hang at exit (docs/blender-compat.md), so everything is unregistered and the process ends
with ``os._exit`` after flushing.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import sys
import time

PACKAGE = "neural_atlas"
ROOT = os.path.dirname(os.path.dirname(os.path.realpath(__file__)))


def parse_args(argv: list[str]) -> argparse.Namespace:
    args = argv[argv.index("--") + 1 :] if "--" in argv else argv[1:]
    p = argparse.ArgumentParser(prog="addon/headless.py", description=__doc__.split("\n\n")[0])
    p.add_argument("manifest", help="manifest.json of an export")
    p.add_argument("--blend", required=True, help=".blend file to write (the compositor tree, plate, edit layers)")
    p.add_argument("--edit", action="append", default=[], metavar="LAYER=IMAGE", help="edit layer for LAYER")
    p.add_argument(
        "--render",
        metavar="DIR",
        help="render every exported frame to DIR/edit.####.exr (the plate's frame number, padded as engine render pads "
        "it: as the plate's files)",
    )
    p.add_argument(
        "--filter",
        choices=("bilinear", "nearest", "exact"),
        default="bilinear",
        help="the edit layers' filter, as `engine render --filter` names it (the render matches it to 1e-5 on every "
        "Blender version); exact: bilinear",
    )
    p.add_argument("--report", metavar="JSON", help="write a JSON report here")
    return p.parse_args(args)


def load_addon():
    """This checkout as the package ``neural_atlas`` (its root ``__init__.py`` is the extension's shim)."""
    if PACKAGE not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            PACKAGE, os.path.join(ROOT, "__init__.py"), submodule_search_locations=[ROOT]
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules[PACKAGE] = module
        spec.loader.exec_module(module)
    return sys.modules[PACKAGE]


def run(ns: argparse.Namespace) -> dict:
    import bpy

    t0 = time.monotonic()
    addon = load_addon()
    from neural_atlas.addon import compositor
    from neural_atlas.addon.core import render_job as RJ
    from neural_atlas.addon.core import tree_plan as P
    from neural_atlas.addon.ops.import_run import import_manifest, set_run_folder
    from neural_atlas.engine import contract as C  # the add-on's only engine import, through the extension package

    edits: dict[str, str] = {}
    for item in ns.edit:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise ValueError(f"--edit {item!r} is not LAYER=IMAGE; write e.g. --edit Foreground=paint.png")
        if not os.path.exists(path):
            raise ValueError(f"{path}: edit image does not exist; check the path given to --edit")
        edits[name] = os.path.abspath(path)
    manifest_path = os.path.abspath(ns.manifest)
    manifest = C.load_manifest(manifest_path)  # ManifestError: one line naming the file and the fix

    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon.register()
    try:
        scene = bpy.context.scene
        filt = P.FILTER_DEFAULT if ns.filter == "exact" else ns.filter
        scene.neural_atlas.filter_type = filt
        # a factory scene's 1-250 is no artist's range: the render is every exported frame (an export of 0-299 too)
        plan = import_manifest(bpy.context, manifest_path, setup_paint=True, edits=edits, set_range=True)
        set_run_folder(bpy.context, manifest_path)  # as Import Atlas does: the opened .blend refines its own run
        blend = os.path.abspath(ns.blend)
        os.makedirs(os.path.dirname(blend), exist_ok=True)
        tmp = blend[: -len(".blend")] + ".tmp.blend" if blend.endswith(".blend") else blend + ".tmp"
        bpy.ops.wm.save_as_mainfile(filepath=tmp, check_existing=False, copy=True)
        os.replace(tmp, blend)  # a half-written .blend never replaces a good one
        files: list[str] = []
        if ns.render:
            names = RJ.output_template(manifest["clip"])  # engine render's names: padded as the plate's files
            files = compositor.render(scene, os.path.abspath(ns.render), "exr", plan.output_colorspace, names)
        report = {
            "blender": bpy.app.version_string,
            "filter": filt,
            # the engine's filter this render matches to float precision: the same name, on every version
            "engine_filter": filt,
            "exact": True,
            "manifest": manifest_path,
            "blend": blend,
            "layers": plan.layers,
            "edits": edits,
            "frames": manifest["passes"]["frames"],
            "files": files,
            "seconds": round(time.monotonic() - t0, 2),
        }
    finally:
        addon.unregister()
    if ns.report:
        os.makedirs(os.path.dirname(os.path.abspath(ns.report)), exist_ok=True)
        with open(ns.report, "w", encoding="utf-8") as f:
            json.dump(report, f, indent=2)
    return report


def remove_session_temp() -> None:
    """Remove Blender's session temp folder (``bpy.app.tempdir``, named ``blender_XXXXXX``): Blender removes it at
    its own exit only, so a process that leaves with ``os._exit`` (the bpy 4.5 exit hang) would leave one behind on
    every run, on every farm node. Nothing when bpy was never imported."""
    bpy = sys.modules.get("bpy")
    folder = getattr(getattr(bpy, "app", None), "tempdir", "") if bpy is not None else ""
    if folder and os.path.basename(os.path.normpath(folder)).startswith("blender_"):
        shutil.rmtree(folder, ignore_errors=True)


def main(argv: list[str]) -> int:
    ns = parse_args(argv)
    try:
        report = run(ns)
    except (ValueError, OSError) as exc:  # ManifestError and PlanError are ValueErrors
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"Blender {report['blender']}: {report['blend']}"
        + (f", {len(report['files'])} frame(s) in {os.path.dirname(report['files'][0])}" if report["files"] else "")
        + f" ({report['seconds']} s)",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    rc = 1
    try:
        rc = main(sys.argv)
    except SystemExit as exc:  # argparse: usage error (2) or --help (0)
        rc = exc.code if isinstance(exc.code, int) else 2
    except BaseException:
        import traceback

        traceback.print_exc()
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        remove_session_temp()
        os._exit(rc)  # bpy 4.5 can hang at interpreter exit (docs/blender-compat.md): leave without it
