"""The extension as an artist gets it: built and validated with Blender's extension CLI, installed with
``package_install_files`` into throw-away user folders (a child process: they must be set before bpy loads)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")

ROOT = Path(__file__).resolve().parents[2]
EXT_ID = "neural_atlas"


def blender_ext_cli() -> str:
    return os.path.join(bpy.utils.resource_path("LOCAL"), "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py")


#: ``blender --command extension ARGS``: Blender's own handler, which sets the valid-tags file to Blender's tag list
#: (scripts/modules/_bpy_internal/extensions/tags.py) before it runs the bundled CLI; the bare CLI checks no tags.
BLENDER_COMMAND_EXTENSION = textwrap.dedent(
    """
    import sys
    import bpy
    from bl_pkg import bl_extension_cli
    sys.exit(bl_extension_cli.cli_extension_handler(sys.argv[1:]))
    """
)


def blender_command_extension(*args: str) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, "-c", BLENDER_COMMAND_EXTENSION, *args]
    return subprocess.run(argv, capture_output=True, text=True, timeout=120)


def test_manifest_passes_blenders_validation_with_its_tag_list():
    """What Blender's extension platform and `blender --command extension validate` check, on this bpy."""
    v = blender_command_extension("validate", str(ROOT))
    assert v.returncode == 0, v.stdout + v.stderr
    assert "Success" in v.stdout, v.stdout


def test_blenders_validation_refuses_a_tag_outside_its_list(tmp_path):
    """The validator above does check tags: the manifest with a tag Blender does not list fails it."""
    manifest = (ROOT / "blender_manifest.toml").read_text(encoding="utf-8")
    assert 'tags = ["Compositing", "Paint", "Tracking"]' in manifest
    (tmp_path / "__init__.py").write_text("")
    (tmp_path / "blender_manifest.toml").write_text(manifest.replace('"Tracking"', '"Video Tools"'), encoding="utf-8")
    v = blender_command_extension("validate", str(tmp_path))
    assert v.returncode != 0
    assert 'found invalid tag "Video Tools"' in v.stdout + v.stderr


def test_manifest_names_website_and_copyright():
    import tomllib

    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text(encoding="utf-8"))
    assert manifest["website"].startswith("https://")
    assert manifest["copyright"] == ["2026 Neural Atlas developers"]
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]


@pytest.fixture(scope="module")
def built_zip(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    cli = blender_ext_cli()
    v = blender_command_extension("validate", str(ROOT))
    assert v.returncode == 0, v.stdout + v.stderr
    b = subprocess.run(
        [sys.executable, cli, "build", "--source-dir", str(ROOT), "--output-dir", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert b.returncode == 0, b.stdout + b.stderr
    zips = list(out.glob("*.zip"))
    assert len(zips) == 1
    return zips[0]


def test_zip_holds_the_extension_and_only_the_built_paths(built_zip):
    names = zipfile.ZipFile(built_zip).namelist()
    assert {"__init__.py", "blender_manifest.toml", "addon/__init__.py", "engine/contract.py"} <= set(names)
    assert {"addon/core/jobs.py", "addon/ops/__init__.py", "addon/ops/driver.py"} <= set(names)
    top = {"__init__.py", "blender_manifest.toml", "addon", "engine", "README.md", "LICENSE"}
    assert {n.split("/")[0] for n in names} <= top and "LICENSE" in names
    assert not any("__pycache__" in n or n.endswith(".pyc") for n in names)
    assert built_zip.name == f"{EXT_ID}-0.1.0.zip"


INSTALL_SCRIPT = textwrap.dedent(
    """
    import json, os, shutil, sys
    import bpy, addon_utils
    zip_path, engine_python = sys.argv[1], sys.argv[2]
    res = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    mod = "bl_ext.user_default.neural_atlas"
    out = {"install": sorted(res), "enabled": mod in bpy.context.preferences.addons}
    prefs = bpy.context.preferences.addons[mod].preferences
    out["prefs_engine_python"] = hasattr(prefs, "engine_python")
    out["panel"] = hasattr(bpy.types, "NEURALATLAS_PT_fit")
    out["import_poll"] = bpy.ops.neural_atlas.import_run.poll()  # Fit Atlas is greyed without a clip
    out["scene_props"] = bpy.context.scene.neural_atlas.preset
    out["installed_dir"] = os.path.dirname(sys.modules[mod].__file__)
    prefs.engine_python = engine_python
    from bl_ext.user_default.neural_atlas.addon import preferences as p
    from bl_ext.user_default.neural_atlas.addon.core import engine_setup
    out["check"] = engine_setup.check_engine(p.engine_python())
    addon_utils.disable(mod, default_set=True)
    out["panel_after_disable"] = hasattr(bpy.types, "NEURALATLAS_PT_fit")
    print("RESULT " + json.dumps(out))
    sys.stdout.flush()
    shutil.rmtree(bpy.app.tempdir, ignore_errors=True)  # Blender's exit would have; os._exit does not
    os._exit(0)
    """
)


def test_install_enable_check_engine_disable(built_zip, tmp_path):
    env = dict(os.environ)
    for key in ("RESOURCES", "EXTENSIONS", "SCRIPTS", "CONFIG"):
        env[f"BLENDER_USER_{key}"] = str(tmp_path / key.lower())
    env.pop("NEURAL_ATLAS_ENGINE_PYTHON", None)
    script = tmp_path / "install.py"
    script.write_text(INSTALL_SCRIPT)
    proc = subprocess.run(
        [sys.executable, str(script), str(built_zip), sys.executable],
        capture_output=True,
        text=True,
        timeout=180,
        env=env,
        cwd=tmp_path,
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert lines, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = json.loads(lines[-1][len("RESULT ") :])
    assert out["install"] == ["FINISHED"] and out["enabled"] and out["prefs_engine_python"]
    assert out["panel"] and out["import_poll"] and out["scene_props"] == "draft"
    assert out["installed_dir"].startswith(str(tmp_path / "extensions"))
    ok, message = out["check"]
    # the engine shipped inside the installed extension answers `python -m engine --version`
    assert ok and message.startswith("neural-atlas engine"), message
    assert not out["panel_after_disable"]


def test_readme_build_command_runs_verbatim():
    """The README's build block, run as written (from the checkout; dist/ is git-ignored and excluded)."""
    import re

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    section = readme[readme.index("## Blender extension") :]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    assert "blender_ext.py" in block and "build" in block
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("the README's command uses .venv")
    zip_path = ROOT / "dist" / f"{EXT_ID}-0.1.0.zip"
    zip_path.unlink(missing_ok=True)
    argv = ["bash", "-euo", "pipefail", "-c", block]
    proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    try:
        names = zipfile.ZipFile(zip_path).namelist()
        assert {"addon/ops/fit.py", "addon/core/jobs.py", "addon/compat.py"} <= set(names)
    finally:
        zip_path.unlink(missing_ok=True)
