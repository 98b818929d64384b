"""The engine's Python (``core.engine_setup``) and the environment of its processes (``core.engine_commands``):
pip's command, the offline explanation, a real set-up that cannot reach an index, and the version check."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest
from helpers import HERE, fake_python, stand_in_pip
from neural_atlas.addon.core import engine_commands as EC
from neural_atlas.addon.core import engine_process as EP
from neural_atlas.addon.core import engine_setup as ES
from neural_atlas.addon.core import running

from engine import contract as C


def test_setup_commands_install_the_contract_requirements():
    argv = ES.pip_install_argv("/x/bin/python")
    assert argv[:4] == ["/x/bin/python", "-m", "pip", "install"]
    assert tuple(argv[-len(C.ENGINE_REQUIREMENTS) :]) == C.ENGINE_REQUIREMENTS
    # at the exact versions tested: the constraints file the extension ships beside the contract
    constraints = argv[argv.index("-c") + 1]
    assert constraints == f"{EC.extension_root()}/engine/constraints.txt"
    assert "torch==2.13.0" in Path(constraints).read_text(encoding="utf-8").split()
    assert EC.engine_argv("py", "fit", "a") == ["py", "-m", "engine", "fit", "a"]
    cpu = ES.pip_install_argv("/x/bin/python", ES.torch_choice(ES.TORCH_CPU, "linux"))
    assert cpu[cpu.index("--extra-index-url") + 1] == "https://download.pytorch.org/whl/cpu"
    env = EC.engine_env({"PYTHONPATH": "/other"})
    assert env["PYTHONPATH"].split(":")[0] == EC.extension_root()
    assert (HERE.parents[1] / "engine" / "contract.py").samefile(f"{EC.extension_root()}/engine/contract.py")


def test_setup_failure_offline_is_explained():
    log = "WARNING: Retrying ... NewConnectionError('Failed to establish a new connection')\nERROR: No matching"
    assert "offline" in ES.explain_setup_failure(log)
    assert ES.explain_setup_failure("ERROR: torch wheel is broken\n") == "ERROR: torch wheel is broken"


@pytest.mark.slow
def test_setup_engine_offline_error_is_clear(tmp_path, monkeypatch):
    """Creates a real venv, then pip cannot reach an index: the report says offline, nothing hangs."""
    for var in ("PIP_FIND_LINKS", "PIP_EXTRA_INDEX_URL"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("PIP_CONFIG_FILE", os.devnull)
    monkeypatch.setenv("PIP_INDEX_URL", "http://127.0.0.1:9/simple")
    monkeypatch.setenv("PIP_RETRIES", "0")
    monkeypatch.setenv("PIP_DEFAULT_TIMEOUT", "2")
    job = ES.SetupJob(str(tmp_path / "venv"))
    lines = []

    def note_label() -> None:
        if job.label not in lines:
            lines.append(job.label)

    job.start()
    note_label()
    EP.run_blocking(job, 120, note_label)  # the blocking path of Set up engine (background mode)
    assert job.result is not None
    ok, message, python = job.result.status == EP.STATUS_OK, job.result.message, job.python
    assert not ok and "offline" in message and str(tmp_path / "venv" / "setup.log") in message
    assert os.path.exists(python)  # the environment itself was created
    assert lines[0] == "creating the environment" and lines[1].startswith("installing torch")
    assert running.jobs() == {}


def test_setup_job_status_shows_pips_latest_line(tmp_path):
    venv = tmp_path / "venv"
    seen = tmp_path / "seen"
    stand_in_pip(venv, release=seen)  # pip's first line stays until this test has seen it
    job = ES.SetupJob(str(venv), ES.torch_choice(ES.TORCH_CPU, "linux"))
    assert [c.label for c in job.commands] == ["installing torch (CPU build) and the engine's packages (about 0.5 GB)"]
    job.start()
    statuses = []
    while job.step():
        statuses.append(job.status_text())
        if statuses[-1].endswith(": Collecting torch==2.13.0"):
            seen.touch()
        time.sleep(0.01)
    assert any(s.startswith("1/1 installing torch") and s.endswith(": Collecting torch==2.13.0") for s in statuses)
    assert job.result is not None and "offline" in job.result.message and "setup.log" in job.result.message


def test_a_cancelled_setup_says_so_and_is_not_explained_as_a_failure(tmp_path):
    """Cancel stops pip (SIGTERM): the result is "cancelled" with its own line, not pip's offline explanation."""
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    pip = venv / "bin" / "python"
    pip.write_text(f"#!{sys.executable}\nimport time\nprint('Collecting torch', flush=True)\ntime.sleep(60)\n")
    pip.chmod(0o755)
    job = ES.SetupJob(str(venv))
    job.start()
    EP.run_blocking(job, 0.5)  # past 0.5 s the job is cancelled, as the Cancel button does
    result = job.result
    assert result is not None and result.status == EP.STATUS_CANCELLED
    assert result.message == f"{ES.CANCELLED_TEXT} (log: {venv / 'setup.log'})"


def test_check_engine_answers_with_the_engines_version(tmp_path):
    ok, message = ES.check_engine(fake_python(tmp_path))
    assert ok and message.startswith("neural-atlas engine")
    ok, message = ES.check_engine(str(tmp_path / "missing_python"))
    assert not ok and message.startswith(f"the engine does not run with {tmp_path / 'missing_python'}: cannot start")
    assert ES.check_engine("") == (False, "no engine Python set: run Set up engine, or choose one in the preferences")


def test_online_access_on_lets_set_up_engine_download():
    assert ES.online_access_refusal(True, False) == ()
    assert ES.online_access_refusal(True, True) == ()  # started with --online-mode


def test_online_access_off_refuses_and_offers_a_python_the_artist_installed():
    lines = ES.online_access_refusal(False, False)
    assert lines == (
        "Online access is off in Blender: Set up engine downloads nothing.",
        "Turn on Preferences > System > Network > Allow Online Access,",
        "or install the engine's packages into a Python yourself (Copy Install Command)",
        "and set Engine Python to it, then Check engine.",
    )


def test_offline_mode_from_the_command_line_is_not_turned_on_by_the_preference():
    lines = ES.online_access_refusal(False, True)
    assert lines[0] == "Blender was started offline (--offline-mode): Set up engine downloads nothing."
    assert lines[1] == "Start Blender without --offline-mode,"
    assert "Preferences" not in " ".join(lines)
    assert lines[2:] == ES.online_access_refusal(False, False)[2:]


def test_manual_setup_command_is_set_up_engines_commands_for_a_shell():
    import shlex

    venv = "/home/artist/my engine"  # a space: quoted for the shell
    words = shlex.split(ES.manual_setup_command(venv, base_python="/opt/blender/python3.11"))
    split = words.index("&&")
    assert words[:split] == ES.create_venv_argv("/opt/blender/python3.11", venv)
    assert words[split + 1 :] == ES.pip_install_argv(ES.venv_python(venv))
    assert tuple(words[-len(C.ENGINE_REQUIREMENTS) :]) == C.ENGINE_REQUIREMENTS
    cpu = shlex.split(ES.manual_setup_command(venv, ES.torch_choice(ES.TORCH_CPU, "linux"), base_python="py"))
    assert cpu[cpu.index("--extra-index-url") + 1] == ES.TORCH_CPU_INDEX


# --- which torch: detection faked, each platform and preference ---------------------------------------------
def _found(*paths):
    """A fake ``which``/``exists`` pair that finds only ``paths``."""
    return (lambda name: name if name in paths else None), (lambda path: path in paths)


def test_an_nvidia_gpu_is_found_by_its_driver():
    which, exists = _found(ES.NVIDIA_PROC)
    assert ES.has_nvidia_gpu("linux", which, exists)  # the kernel module, without nvidia-smi on PATH
    which, exists = _found("nvidia-smi")
    assert ES.has_nvidia_gpu("linux", which, exists) and ES.has_nvidia_gpu("win32", which, exists)
    which, exists = _found(ES.NVIDIA_SMI_WINDOWS)
    assert ES.has_nvidia_gpu("win32", which, exists) and not ES.has_nvidia_gpu("linux", which, exists)
    which, exists = _found()
    assert not ES.has_nvidia_gpu("linux", which, exists) and not ES.has_nvidia_gpu("win32", which, exists)
    which, exists = _found("nvidia-smi", ES.NVIDIA_PROC)
    assert not ES.has_nvidia_gpu("darwin", which, exists)  # no CUDA on macOS


def test_auto_picks_cuda_with_an_nvidia_gpu_and_cpu_without():
    cuda = ES.torch_choice(ES.TORCH_AUTO, "linux", nvidia=True)
    assert (cuda.build, cuda.index_url) == (ES.TORCH_CUDA, None)  # PyPI's Linux torch is the CUDA build
    assert cuda.download_gb == ES.TORCH_DOWNLOAD_GB[ES.TORCH_CUDA] == 3.5 and cuda.why == "Auto: an NVIDIA GPU found"
    cpu = ES.torch_choice(ES.TORCH_AUTO, "linux", nvidia=False)
    assert (cpu.build, cpu.index_url, cpu.download_gb) == (ES.TORCH_CPU, "https://download.pytorch.org/whl/cpu", 0.5)
    assert cpu.why == "Auto: no NVIDIA GPU found"
    win = ES.torch_choice(ES.TORCH_AUTO, "win32", nvidia=True)
    assert (win.build, win.index_url) == (ES.TORCH_CUDA, ES.TORCH_CUDA_WINDOWS_INDEX)  # PyPI's Windows torch is CPU
    assert ES.torch_choice(ES.TORCH_AUTO, "win32", nvidia=False).index_url == ES.TORCH_CPU_INDEX
    mac = ES.torch_choice(ES.TORCH_CUDA, "darwin", nvidia=True)
    assert (mac.build, mac.index_url, mac.download_gb) == (ES.TORCH_MAC, None, 0.4)  # the default wheel, with MPS


def test_the_preference_overrides_the_detection():
    assert ES.torch_choice(ES.TORCH_CPU, "linux", nvidia=True).build == ES.TORCH_CPU
    forced = ES.torch_choice(ES.TORCH_CUDA, "linux", nvidia=False)
    assert forced.build == ES.TORCH_CUDA and forced.why == "chosen in the preferences (CUDA)"
    import pytest

    with pytest.raises(ValueError, match="unknown torch build"):
        ES.torch_choice("ROCM", "linux")


def test_the_choice_reaches_pip_the_set_up_step_and_the_preferences(tmp_path):
    import shlex

    for setting, nvidia, index in ((ES.TORCH_AUTO, False, ES.TORCH_CPU_INDEX), (ES.TORCH_AUTO, True, None)):
        choice = ES.torch_choice(setting, "linux", nvidia=nvidia)
        argv = ES.pip_install_argv("/v/bin/python", choice)
        assert ("--extra-index-url" in argv) == (index is not None)
        if index:
            assert argv[argv.index("--extra-index-url") + 1] == index
        assert shlex.split(ES.manual_setup_command("/v", choice, "py"))[-len(argv) :] == argv
    cuda = ES.torch_choice(ES.TORCH_CUDA, "linux")
    job = ES.SetupJob(str(tmp_path / "venv"), cuda)
    assert job.commands[-1].label == "installing torch (CUDA build) and the engine's packages (about 3.5 GB)"
    assert "--extra-index-url" not in job.commands[-1].argv
    assert ES.torch_lines(cuda) == (
        "Set up engine installs torch's CUDA build: about 3.5 GB",
        "chosen in the preferences (CUDA); from PyPI",
    )
    assert ES.torch_lines(ES.torch_choice(ES.TORCH_CPU, "linux"))[1].endswith(
        "; from https://download.pytorch.org/whl/cpu"
    )
