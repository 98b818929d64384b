"""The engine's Python: create it, install its requirements, check that it runs the engine. No bpy here.

The engine runs with its own interpreter (Blender's Python has no torch): a virtual environment in the
extension's user folder with ``contract.ENGINE_REQUIREMENTS`` installed at the exact versions of the constraints
file shipped beside it, and the extension's own folder on PYTHONPATH (``engine_commands.engine_env``) so
``python -m engine`` finds the engine shipped inside it.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass

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
#: The CUDA build on Windows (PyPI's Windows torch is the CPU build): PyTorch's CUDA 12.8 wheels.
TORCH_CUDA_WINDOWS_INDEX = "https://download.pytorch.org/whl/cu128"
#: The Torch Build preference: pick for this machine, or the artist's choice.
TORCH_AUTO, TORCH_CPU, TORCH_CUDA = "AUTO", "CPU", "CUDA"
#: macOS: PyPI's default wheel (it has the Apple GPU backend, MPS; there is no CUDA build).
TORCH_MAC = "MAC"
#: Approximate download of the engine's packages in GB, per torch build: torch's wheel and the libraries pip fetches
#: with it (the CUDA build brings the nvidia-* CUDA, cuDNN and NCCL wheels), plus the other requirements
#: (about 0.2 GB: OpenCV, OpenImageIO, SciPy, PyAV, numpy). The sizes of the published wheels, rounded up.
TORCH_DOWNLOAD_GB = {TORCH_CPU: 0.5, TORCH_CUDA: 3.5, TORCH_MAC: 0.4}
#: Where each build comes from: an extra index for pip (PyPI's default wheel when None), per platform.
TORCH_INDEX = {
    ("linux", TORCH_CPU): TORCH_CPU_INDEX,
    ("linux", TORCH_CUDA): None,
    ("win32", TORCH_CPU): TORCH_CPU_INDEX,
    ("win32", TORCH_CUDA): TORCH_CUDA_WINDOWS_INDEX,
}
#: Where Linux's NVIDIA driver shows itself (present once the kernel module is loaded).
NVIDIA_PROC = "/proc/driver/nvidia"
#: Windows's NVIDIA driver installs nvidia-smi here (and usually on PATH too).
NVIDIA_SMI_WINDOWS = r"C:\Windows\System32\nvidia-smi.exe"
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


def platform_key(platform: str = sys.platform) -> str:
    """``sys.platform`` as the torch choice knows it: "linux", "win32" or "darwin" (other Unixes count as Linux)."""
    if platform.startswith("win"):
        return "win32"
    return "darwin" if platform == "darwin" else "linux"


def has_nvidia_gpu(
    platform: str = sys.platform,
    which: Callable[[str], str | None] = shutil.which,
    exists: Callable[[str], bool] = os.path.exists,
) -> bool:
    """Whether this machine has an NVIDIA GPU with its driver: Linux's ``/proc/driver/nvidia`` or ``nvidia-smi``
    (both come with the driver); on Windows ``nvidia-smi``; never on macOS. Nothing is run: only looked up."""
    key = platform_key(platform)
    if key == "darwin":
        return False
    if key == "linux" and exists(NVIDIA_PROC):
        return True
    return which("nvidia-smi") is not None or (key == "win32" and exists(NVIDIA_SMI_WINDOWS))


@dataclass(frozen=True)
class TorchChoice:
    """The torch build Set up engine installs: ``build`` (CPU, CUDA or MAC), pip's extra index for it (None:
    PyPI's default wheel), the approximate download in GB, and why it was picked (the preferences' line)."""

    build: str
    index_url: str | None
    download_gb: float
    why: str

    @property
    def name(self) -> str:
        return {TORCH_CPU: "CPU build", TORCH_CUDA: "CUDA build", TORCH_MAC: "macOS build (MPS)"}[self.build]

    def label(self) -> str:
        """What the set-up step says: ``installing torch (CPU build) and the engine's packages (about 0.5 GB)``."""
        return f"installing torch ({self.name}) and the engine's packages (about {self.download_gb:g} GB)"


def torch_choice(setting: str = TORCH_AUTO, platform: str = sys.platform, nvidia: bool | None = None) -> TorchChoice:
    """The torch build for ``setting`` (Auto: CUDA where there is an NVIDIA GPU, ``has_nvidia_gpu`` unless
    ``nvidia`` says; else CPU) on ``platform``. macOS always takes PyPI's wheel (MPS; no CUDA there)."""
    key = platform_key(platform)
    if key == "darwin":
        return TorchChoice(TORCH_MAC, None, TORCH_DOWNLOAD_GB[TORCH_MAC], "macOS: the default wheel (Apple GPU, MPS)")
    if setting == TORCH_AUTO:
        gpu = has_nvidia_gpu(platform) if nvidia is None else nvidia
        build = TORCH_CUDA if gpu else TORCH_CPU
        why = "Auto: an NVIDIA GPU found" if gpu else "Auto: no NVIDIA GPU found"
    elif setting in (TORCH_CPU, TORCH_CUDA):
        build, why = setting, f"chosen in the preferences ({setting})"
    else:
        raise ValueError(f"unknown torch build {setting!r}: use one of {TORCH_AUTO}, {TORCH_CPU}, {TORCH_CUDA}")
    return TorchChoice(build, TORCH_INDEX[(key, build)], TORCH_DOWNLOAD_GB[build], why)


def pip_install_argv(python: str, torch: TorchChoice | None = None) -> list[str]:
    """pip's command for the engine's requirements (ranges) at the exact versions the engine was tested with (the
    constraints file shipped beside the contract); the chosen torch build's index as an extra index (pip takes its
    ``torch==X+cpu``/``+cu128`` over PyPI's ``torch==X``: a local version sorts after the plain one)."""
    index = torch.index_url if torch is not None else None
    extra = ["--extra-index-url", index] if index else []
    pins = ["-c", str(C.CONSTRAINTS_PATH)]
    return [python, "-m", "pip", "install", "--progress-bar", "off", *extra, *pins, *C.ENGINE_REQUIREMENTS]


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


def manual_setup_command(venv_dir: str, torch: TorchChoice | None = None, base_python: str = sys.executable) -> str:
    """The shell command that does what Set up engine does (the same environment, the same pinned packages, the
    same torch build), for the artist to run in a terminal where they choose how pip reaches its packages (an index,
    a proxy, a folder of wheels with ``--find-links``); Engine Python is then ``venv_python(venv_dir)``."""
    create = shlex.join(create_venv_argv(base_python, venv_dir))
    return f"{create} && {shlex.join(pip_install_argv(venv_python(venv_dir), torch))}"


def torch_lines(torch: TorchChoice) -> tuple[str, str]:
    """The preferences' two lines about the torch build: what is installed and how large, and why."""
    return (
        f"Set up engine installs torch's {torch.name}: about {torch.download_gb:g} GB",
        f"{torch.why}; from {torch.index_url or 'PyPI'}",
    )


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

    def __init__(self, venv_dir: str, torch: TorchChoice | None = None, base_python: str = sys.executable):
        self.python = venv_python(venv_dir)
        self.torch = torch or torch_choice()
        os.makedirs(venv_dir, exist_ok=True)
        commands = []
        if not os.path.exists(self.python):
            commands.append(Command("creating the environment", create_venv_argv(base_python, venv_dir)))
        pip = pip_install_argv(self.python, self.torch)
        commands.append(Command(self.torch.label(), pip))
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
