"""The add-on's Save Edits on an export's edit layers, in Blender (the bpy wheel, in a subprocess like
test_export_in_blender): it holds the run folder's lock (another process holding it is one line in the UI and
nothing is written) and saves atomically (a really full disk leaves the edit layer byte-identical and the paint
unsaved in Blender, and Save Edits works once there is room). Skipped when bpy is not installed."""

from __future__ import annotations

import hashlib
import importlib.util
import json
import subprocess
import sys

import pytest

from tests.folders import hold_lock
from tests.full_disk import run_on_full_disk
from tests.paths import ROOT

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="bpy is not installed")

#: argv: MODE FOLDER. Makes a fake export in FOLDER (unless it is there; MODE "make" stops there), imports it with
#: the add-on, paints on the background's edit layer and saves; prints one RESULT line of JSON.
SCRIPT = r"""
import hashlib, importlib.util, json, os, sys, traceback
sys.excepthook = lambda *exc: (traceback.print_exception(*exc), sys.stderr.flush(), os._exit(1))
from pathlib import Path
import bpy
import numpy as np
root = Path(os.getcwd())
sys.path.insert(0, str(root))
init, package = root / "__init__.py", [str(root)]
spec = importlib.util.spec_from_file_location("neural_atlas", init, submodule_search_locations=package)
addon = importlib.util.module_from_spec(spec); sys.modules["neural_atlas"] = addon; spec.loader.exec_module(addon)
from tests.engine.fake_export import make_fake_export
mode, folder = sys.argv[1], Path(sys.argv[2])
manifest = folder / "run" / "exports" / "v001" / "manifest.json"
if not manifest.exists():
    layer = (lambda t, xs, ys: (xs / 32, 1.0 - ys / 24, np.ones(xs.shape)), (32, 24))
    make_fake_export(folder, np.full((2, 24, 32, 3), 0.5, np.float32), [layer])
if mode == "make":
    os._exit(0)
edit = folder / "run" / "edits" / "Background.png"
addon.register()
bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest), setup_paint=False)
img = bpy.data.images["NA_Edit_Background"]

def paint(value):
    px = np.zeros(32 * 24 * 4, np.float32)
    img.pixels.foreach_get(px)
    px.reshape(24, 32, 4)[2:10, 2:10] = (value, 0.0, 0.0, 1.0)
    img.pixels.foreach_set(px)

def save():
    try:
        return sorted(bpy.ops.neural_atlas.save_edits("EXEC_DEFAULT")), ""
    except RuntimeError as exc:  # an operator's ERROR report, raised when it is called from Python
        return ["CANCELLED"], str(exc)

def digest():
    return hashlib.sha256(edit.read_bytes()).hexdigest()

out = {"before": digest()}
paint(1.0)
if mode == "full":
    out["first"] = save()  # the run folder's lock file exists from here on
    out["saved"] = digest()
    paint(0.25)
    filler = folder / "filler"
    with open(filler, "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * 4096); f.flush()
        except OSError:
            pass
out["result"], out["error"] = save()
out["after"], out["dirty"] = digest(), img.is_dirty
out["hidden"] = sorted(p.name for p in edit.parent.iterdir() if p.name.startswith(".saving") or ".saving-" in p.name)
if mode == "full":
    filler.unlink()
    out["again"], out["again_error"] = save()
    out["final"] = digest()
addon.unregister()
print("RESULT " + json.dumps(out), flush=True)
os._exit(0)
"""


def _result(stdout: str, stderr: str) -> dict:
    lines = [line for line in stdout.splitlines() if line.startswith("RESULT ")]
    assert lines, stdout[-3000:] + stderr[-3000:]
    return json.loads(lines[0][len("RESULT ") :])


def test_save_edits_refuses_a_run_folder_another_process_holds(tmp_path):
    """A fit (a child holding the lock) owns the run folder: Save Edits is refused with one line naming it and
    writes nothing; the paint stays unsaved in Blender."""
    subprocess.run([sys.executable, "-c", SCRIPT, "make", str(tmp_path)], cwd=ROOT, capture_output=True, timeout=300)
    holder = hold_lock(tmp_path / "run")
    try:
        proc = subprocess.run(
            [sys.executable, "-c", SCRIPT, "locked", str(tmp_path)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
        )
    finally:
        holder.kill()
        holder.wait()
    got = _result(proc.stdout, proc.stderr)
    assert got["result"] == ["CANCELLED"] and f"in use by fit (pid {holder.pid} on " in got["error"], got
    assert "\n" not in got["error"].strip()
    assert got["after"] == got["before"] and got["dirty"] and got["hidden"] == []


def test_save_edits_on_a_full_disk_keeps_the_edit_layer_and_the_paint(tmp_path):
    """The export on a tmpfs filled to the last byte: Save Edits fails in one line, the edit layer is byte-identical
    to its last save, no temporary file is left, the paint is still unsaved in Blender; with room again it saves."""
    disk = tmp_path / "disk"
    run = run_on_full_disk([sys.executable, "-c", SCRIPT, "full", str(disk)], mount=disk, size_kb=4096, cwd=ROOT)
    got = _result(run.stdout, run.stderr)
    assert got["first"] == [["FINISHED"], ""] and got["saved"] != got["before"], got
    assert got["result"] == ["CANCELLED"] and "could not be saved" in got["error"], got
    assert got["after"] == got["saved"] and got["dirty"] and got["hidden"] == [], got
    assert got["again"] == ["FINISHED"] and got["final"] not in (got["saved"], got["before"]), got
    assert hashlib.sha256(b"").hexdigest() not in (got["after"], got["final"])
