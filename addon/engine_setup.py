"""Commands that find, create and check the engine's Python. No bpy here.

The engine runs with its own interpreter (Blender's Python has no torch): a virtual environment in the
extension's user folder with ``contract.ENGINE_REQUIREMENTS`` installed, and the extension's own folder
on PYTHONPATH so ``python -m engine`` finds the engine shipped inside the extension.
"""

from __future__ import annotations

import os
import sys

from ..engine import contract as C

#: pip output that means the package index cannot be reached (the "Set up engine" error says so plainly)
OFFLINE_MARKERS = (
    "NewConnectionError",
    "Failed to establish a new connection",
    "Temporary failure in name resolution",
    "Could not find a version that satisfies the requirement",
    "No matching distribution found",
    "Network is unreachable",
    "Connection refused",
    "ProxyError",
)


def extension_root() -> str:
    """The folder that holds ``engine/`` and ``addon/`` (the extension root, or the checkout)."""
    return os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def venv_python(venv_dir: str) -> str:
    if sys.platform == "win32":
        return os.path.join(venv_dir, "Scripts", "python.exe")
    return os.path.join(venv_dir, "bin", "python")


def engine_env(base: dict[str, str] | None = None) -> dict[str, str]:
    """Environment for engine processes: the extension root first on PYTHONPATH, unbuffered output."""
    env = dict(os.environ if base is None else base)
    root = extension_root()
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["PYTHONUNBUFFERED"] = "1"
    return env


def engine_argv(python: str, verb: str, *args: str) -> list[str]:
    return [python, "-m", C.CLI_MODULE, verb, *args]


def version_argv(python: str) -> list[str]:
    return [python, "-m", C.CLI_MODULE, "--version"]


def create_venv_argv(base_python: str, venv_dir: str) -> list[str]:
    return [base_python, "-m", "venv", venv_dir]


#: PyTorch's CPU-only wheels (on Linux, PyPI's torch is a multi-GB CUDA build)
TORCH_CPU_INDEX = "https://download.pytorch.org/whl/cpu"


def pip_install_argv(python: str, cpu_only: bool = False) -> list[str]:
    extra = ["--extra-index-url", TORCH_CPU_INDEX] if cpu_only else []
    return [python, "-m", "pip", "install", "--progress-bar", "off", *extra, *C.ENGINE_REQUIREMENTS]


def explain_setup_failure(log_text: str) -> str:
    """One line for the artist from pip's output."""
    if any(marker in log_text for marker in OFFLINE_MARKERS):
        return (
            "cannot download the engine's packages (offline, or the package index is unreachable): "
            "connect to the internet and run Set up engine again, or point Engine Python at a Python "
            "that already has them"
        )
    lines = [ln.strip() for ln in log_text.splitlines() if ln.strip().startswith("ERROR")]
    return lines[-1] if lines else "installing the engine's packages failed"
