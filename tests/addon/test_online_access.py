"""Set up engine and Blender's online access: no download while it is off; the preferences say so and offer a
Python the artist installed. ``bpy.app.online_access`` is read-only, but it follows the preference
``preferences.system.use_online_access`` (unless Blender was started with --offline-mode/--online-mode, which a
bpy module cannot be: that case is the pure decision's, tests/addon/core/test_engine_setup.py)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

bpy = pytest.importorskip("bpy")

from helpers import RecordingLayout, as_operator  # noqa: E402
from neural_atlas.addon import preferences  # noqa: E402
from neural_atlas.addon.core import engine_setup as ES  # noqa: E402
from neural_atlas.addon.core import running  # noqa: E402
from neural_atlas.addon.ops import setup as setup_ops  # noqa: E402


@pytest.fixture
def online(blender):
    """Set Blender's online access for a test (factory settings have it off); restored after."""
    system = blender.context.preferences.system
    before = system.use_online_access

    def set_to(on: bool) -> None:
        system.use_online_access = on
        assert bpy.app.online_access is on and not bpy.app.online_access_override

    yield set_to
    system.use_online_access = before


def _draw_preferences() -> list[tuple[str, tuple, dict]]:
    """The preferences' ``draw`` with a recording layout (it never runs headless: no region is drawn)."""
    layout = RecordingLayout()
    prefs = SimpleNamespace(layout=layout, setup_status="", farm_kind="openjd")
    preferences.NEURALATLAS_AP_preferences.draw(prefs, bpy.context)
    return layout.calls


def test_read_of_blenders_state_is_the_pure_decision(online):
    for on in (False, True):
        online(on)
        assert preferences.online_refusal() == ES.online_access_refusal(on, False)


def test_set_up_engine_is_refused_offline_and_downloads_nothing(online, tmp_path):
    online(False)
    venv = tmp_path / "venv"
    assert not bpy.ops.neural_atlas.setup_engine.poll()
    with pytest.raises(RuntimeError, match="Online access is off in Blender: Set up engine downloads nothing"):
        bpy.ops.neural_atlas.setup_engine("EXEC_DEFAULT", venv_dir=str(venv))
    # a call that skips poll (the job's own start) is refused the same way, before anything is created
    op = as_operator(setup_ops.NEURALATLAS_OT_setup_engine, venv_dir=str(venv))
    assert op._begin(bpy.context) is None
    assert op.reports == [({"ERROR"}, " ".join(ES.online_access_refusal(False, False)))]
    assert not venv.exists() and running.jobs() == {}
    online(True)
    assert bpy.ops.neural_atlas.setup_engine.poll()


def test_preferences_say_so_and_offer_the_install_command_only_offline(online):
    online(False)
    calls = _draw_preferences()
    labels = [kw["text"] for name, _, kw in calls if name == "label"]
    assert labels[:4] == list(ES.online_access_refusal(False, False))
    ops = [a[0] for name, a, _ in calls if name == "operator"]
    assert ops == ["neural_atlas.copy_setup_command", "neural_atlas.setup_engine", "neural_atlas.check_engine"]
    online(True)
    calls = _draw_preferences()
    assert not any(name == "label" and kw.get("text", "").startswith("Online") for name, _, kw in calls)
    assert [a[0] for name, a, _ in calls if name == "operator"] == [
        "neural_atlas.setup_engine",
        "neural_atlas.check_engine",
    ]


def test_copy_install_command_puts_set_up_engines_command_on_the_clipboard(online, monkeypatch, tmp_path):
    online(False)
    venv = tmp_path / "engine_venv"
    monkeypatch.setattr(preferences, "default_venv_dir", lambda: str(venv))
    op = as_operator(setup_ops.NEURALATLAS_OT_copy_setup_command)
    assert op.execute(bpy.context) == {"FINISHED"}
    torch = preferences.torch_choice(bpy.context)
    size = f"torch {torch.name}, about {torch.download_gb:g} GB"
    assert op.reports == [
        ({"INFO"}, f"copied ({size}): run it in a terminal, then set Engine Python to {venv}/bin/python")
    ]
    assert bpy.ops.neural_atlas.copy_setup_command() == {"FINISHED"}
    # a bpy module without a window system keeps no clipboard (it reads back empty); Blender's does
    assert bpy.context.window_manager.clipboard in ("", ES.manual_setup_command(str(venv), torch))


def test_fit_panel_points_to_engine_python_when_offline_and_none_is_set(online, monkeypatch):
    from neural_atlas.addon import ui

    monkeypatch.delenv(preferences.ENGINE_PYTHON_ENV, raising=False)
    layout = RecordingLayout()
    for on, expected in ((False, True), (True, False)):
        online(on)
        calls = layout.draw(ui.NEURALATLAS_PT_fit, bpy.context)
        labels = [kw.get("text") for name, _, kw in calls if name == "label"]
        assert labels[0] == "Set up the engine in the preferences"
        assert ("Online access is off: set Engine Python there" in labels) is expected
