"""The licence the project declares (GPL-3.0-or-later) travels with it: the full GPL version 3 text as LICENSE in the
checkout, in the wheel (``dist-info/licenses/LICENSE``) and at the top of the Blender extension's zip."""

from __future__ import annotations

import hashlib
import importlib.util
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from engine.terms.versions import ENGINE_VERSION
from tests.packaging.test_package import source, wheel  # noqa: F401 (fixtures: a copy of the checkout, its wheel)
from tests.paths import ROOT

LICENSE = ROOT / "LICENSE"
#: SHA-256 of the GNU GPL version 3 text as the FSF publishes it (https://www.gnu.org/licenses/gpl-3.0.txt).
GPL3_SHA256 = "3972dc9744f6499f0f9b2dbf76696f2ae7ad8af9b23dde66d6af86c9dfb36986"


def test_the_checkout_holds_the_gpl_version_3():
    text = LICENSE.read_text(encoding="utf-8")
    lines = [line.strip() for line in text.splitlines()]
    assert lines[:2] == ["GNU GENERAL PUBLIC LICENSE", "Version 3, 29 June 2007"]
    assert "END OF TERMS AND CONDITIONS" in lines and len(lines) == 674
    assert hashlib.sha256(LICENSE.read_bytes()).hexdigest() == GPL3_SHA256


def test_pyproject_and_the_extension_manifest_name_it():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert project["license"] == "GPL-3.0-or-later" and project["license-files"] == ["LICENSE"]
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text(encoding="utf-8"))
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]


def test_the_wheel_carries_it(wheel):  # noqa: F811 (the fixture)
    dist_info = f"neural_atlas-{ENGINE_VERSION}.dist-info"
    with zipfile.ZipFile(wheel) as z:
        assert z.read(f"{dist_info}/licenses/LICENSE") == LICENSE.read_bytes()
        metadata = z.read(f"{dist_info}/METADATA").decode()
    assert "License-Expression: GPL-3.0-or-later" in metadata.splitlines()
    assert "License-File: LICENSE" in metadata.splitlines()


def test_the_extension_zip_carries_it(tmp_path):
    """Built as tests/addon/test_extension.py builds it: Blender's extension CLI on the checkout."""
    spec = importlib.util.find_spec("bpy")  # found, not imported: Blender stays out of this process
    if spec is None or spec.origin is None:
        pytest.skip("no bpy here: its extension CLI builds the zip")
    (cli,) = Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py")
    argv = [sys.executable, cli, "build", "--source-dir", str(ROOT), "--output-dir", str(tmp_path)]
    built = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert built.returncode == 0, built.stdout + built.stderr
    (zip_path,) = tmp_path.glob("*.zip")
    with zipfile.ZipFile(zip_path) as z:
        assert z.read("LICENSE") == LICENSE.read_bytes()
