"""The engine's Python: create it, install its requirements, check that it runs the engine. No bpy here.

The engine runs with its own interpreter (Blender's Python has no torch): a virtual environment in the
extension's user folder with ``contract.ENGINE_REQUIREMENTS`` installed, and the extension's own folder
on PYTHONPATH (``engine_commands.engine_env``) so ``python -m engine`` finds the engine shipped inside it.
"""

from __future__ import annotations

import os
import shlex
import sys
import tempfile

from ...engine import contract as C  # type: ignore[import-not-found]
from . import engine_commands as EC
from . import engine_process as EP
from . import progress
from .jobs import Command, Job, failed

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
#: PyTorch's CPU-only wheels (on Linux, PyPI's torch is a multi-GB CUDA build)
TORCH_CPU_INDEX = "https://download.pytorch.org/whl/cpu"
#: Set up engine in background mode (no event loop: it blocks) gives up after this long; torch is a large download.
SETUP_TIMEOUT_SECONDS = 3600.0
#: ``python -m engine --version`` answers within this, or the engine Python is reported as not working.
CHECK_TIMEOUT_SECONDS = 120.0
#: How much of pip's latest line the status shows.
STATUS_LINE_CHARS = 80


def venv_python(venv_dir: str) -> str:
    if sys.platform == "win32":
        return os.path.join(venv_dir, "Scripts", "python.exe")
    return os.path.join(venv_dir, "bin", "python")


def create_venv_argv(base_python: str, venv_dir: str) -> list[str]:
    return [base_python, "-m", "venv", venv_dir]


def pip_install_argv(python: str, cpu_only: bool = False) -> list[str]:
    extra = ["--extra-index-url", TORCH_CPU_INDEX] if cpu_only else []
    return [python, "-m", "pip", "install", "--progress-bar", "off", *extra, *C.ENGINE_REQUIREMENTS]


#: Blender's switch for network use (extensions may use the network only while it is on), as its UI names it.
ONLINE_ACCESS_SETTING = "Preferences > System > Network > Allow Online Access"


def online_access_refusal(online_access: bool, forced: bool) -> tuple[str, ...]:
    """Why Set up engine must not download now, in short lines for the preferences (the first is the headline;
    joined, the operator's report); () when it may. Blender asks every extension to use the network only while
    ``bpy.app.online_access`` is on; ``forced`` is ``bpy.app.online_access_override``: Blender was started with
    ``--offline-mode``, so the preference cannot turn it on. The other way in needs no network from Blender: a
    Python the artist installed the engine's packages into (``manual_setup_command``), set as Engine Python."""
    if online_access:
        return ()
    if forced:
        headline, turn_on = "Blender was started offline (--offline-mode):", "Start Blender without --offline-mode,"
    else:
        headline, turn_on = "Online access is off in Blender:", f"Turn on {ONLINE_ACCESS_SETTING},"
    return (
        f"{headline} Set up engine downloads nothing.",
        turn_on,
        "or install the engine's packages into a Python yourself (Copy Install Command)",
        "and set Engine Python to it, then Check engine.",
    )


def manual_setup_command(venv_dir: str, cpu_only: bool = False, base_python: str = sys.executable) -> str:
    """The shell command that does what Set up engine does (the same environment, the same pinned packages), for
    the artist to run in a terminal where they choose how pip reaches its packages (an index, a proxy, a folder of
    wheels with ``--find-links``); Engine Python is then ``venv_python(venv_dir)``."""
    create = shlex.join(create_venv_argv(base_python, venv_dir))
    return f"{create} && {shlex.join(pip_install_argv(venv_python(venv_dir), cpu_only))}"


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


#: What Set up engine says when Cancel stopped it.
CANCELLED_TEXT = "Set up engine cancelled: what it installed stays; Set up engine again installs the rest"


class SetupJob(Job):
    """Set up engine: create the venv (unless it exists), then pip-install the pinned requirements."""

    def __init__(self, venv_dir: str, cpu_only: bool = False, base_python: str = sys.executable):
        self.python = venv_python(venv_dir)
        os.makedirs(venv_dir, exist_ok=True)
        commands = []
        if not os.path.exists(self.python):
            commands.append(Command("creating the environment", create_venv_argv(base_python, venv_dir)))
        pip = pip_install_argv(self.python, cpu_only)
        commands.append(Command("installing torch and the engine's packages (about 1 GB)", pip))
        super().__init__(commands, os.path.join(venv_dir, "setup.log"))

    def status_text(self) -> str:
        """The command, and pip's latest line (Collecting…, Downloading…)."""
        last = self.state.last_stdout
        return f"{self.index + 1}/{len(self.commands)} {self.label}" + (f": {last[:STATUS_LINE_CHARS]}" if last else "")

    def finish(self, result: EP.JobResult) -> EP.JobResult:
        if result.status == EP.STATUS_CANCELLED:  # Cancel (pip stopped by SIGTERM), not a failure to explain
            result.message = f"{CANCELLED_TEXT} (log: {self.log_path})"
            return result
        if result.status != EP.STATUS_OK:
            return failed(result, f"{explain_setup_failure(progress.read_log(self.log_path))} (log: {self.log_path})")
        result.message = f"engine ready: {self.python}"
        return result


def check_engine(python: str) -> tuple[bool, str]:
    """Does ``python -m engine --version`` answer? (ok, its answer or what went wrong)."""
    if not python:
        return False, "no engine Python set: run Set up engine, or choose one in the preferences"
    log = os.path.join(tempfile.gettempdir(), "neural_atlas_check.log")
    job = EP.EngineJob(EC.version_argv(python), log, env=EC.engine_env()).start()
    result = job.wait(timeout=CHECK_TIMEOUT_SECONDS)
    if result.status == EP.STATUS_OK and job.state.last_stdout:
        return True, job.state.last_stdout
    return False, f"the engine does not run with {python}: {result.message} (log: {log})"
