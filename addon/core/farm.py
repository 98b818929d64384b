"""Submit to Farm: the shots file for the panel's clip, and the engine command that sends it. No bpy here.

The add-on does not schedule anything itself: it describes the clip as a one-shot shots file (the engine's format,
``engine.contract``'s ``SHOTS_*`` names) and runs ``python -m engine farm flamenco SHOTS --manager URL`` (a job on a
Flamenco Manager) or ``farm openjd SHOTS --out BUNDLE`` (an Open Job Description bundle for Deadline Cloud). The
engine turns the file into the farm's tasks, so the farm runs the very command lines a local fit would, and the
run folder it fills is the one Fit Atlas would have used: Import reads it the same way.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from urllib.parse import urlsplit

from ...engine import contract as C  # type: ignore[import-not-found]
from . import engine_commands as EC
from . import engine_process as EP
from .engine_setup import ONLINE_ACCESS_SETTING
from .errors import UserError
from .jobs import Command, Job, failed
from .run_files import RunFiles, fresh_dir

#: The farms the add-on submits to (the engine's ``farm`` commands).
FARM_FLAMENCO = C.FARM_FLAMENCO
FARM_OPENJD = C.FARM_OPENJD
FARM_KINDS: tuple[str, ...] = (FARM_FLAMENCO, FARM_OPENJD)
#: Where a Flamenco Manager listens out of the box (its own default port).
DEFAULT_MANAGER_URL = "http://localhost:8080"
#: Flamenco's default job priority (0-100, higher runs first).
DEFAULT_PRIORITY = 50
PRIORITY_MIN, PRIORITY_MAX = 0, 100
#: The bundle folder's name (beside the run folder, or under the preference's folder in a folder per shot).
BUNDLE_FOLDER_NAME = "openjd"
#: The longest shot name the engine takes (it names folders, task ids and OpenJD steps).
SHOT_NAME_MAX = C.SHOT_NAME_MAX
#: What a farm job's shot is called when the clip's name has nothing usable in it.
FALLBACK_SHOT_NAME = "shot"

#: Blender's colour-space names of a plate -> the engine's (OCIO's built-in config), inverse of
#: ``colorspaces.BLENDER_COLORSPACES``: the farm reads the plate in the space the artist sees it in Blender.
ENGINE_COLORSPACES: dict[str, str] = {
    "sRGB": C.COLOUR_SRGB,
    "Linear Rec.709": C.COLOUR_SCENE_LINEAR,
    "Non-Color": C.COLOUR_RAW,
    "ACEScg": "ACEScg",
    "ACES2065-1": "ACES2065-1",
    "ACEScct": "ACEScct",
    "ACEScc": "ACEScc",
}


@dataclass(frozen=True)
class FarmSettings:
    """The preferences' farm settings. ``bundle_dir`` '': bundles go beside the Run Folder."""

    kind: str = FARM_FLAMENCO
    manager_url: str = DEFAULT_MANAGER_URL
    priority: int = DEFAULT_PRIORITY
    bundle_dir: str = ""


@dataclass(frozen=True)
class FarmShot:
    """One shot as the farm gets it: the plate as the engine reads it (a sequence's pattern or the movie), its mask
    folders (none: the engine finds the moving objects first), the frames in the plate's numbers, the fit's preset and
    ``--set`` items, the Run Folder, and the plate's colour space in the engine's words (None: the engine's rules)."""

    name: str
    plate: str
    masks: tuple[str, ...]
    first: int
    last: int
    preset: str
    sets: tuple[str, ...]
    run_dir: str
    colorspace: str | None = None
    follow_flow: bool = True
    """False: the export's UV as fitted (the shots file's ``follow_flow``, ``export --no-follow-flow``)."""
    auto_parts: bool = True
    """False (Find Parts off): the shot's ``auto_parts`` false, the one object fitted as one layer; True: the key
    left out, the fit's default (the parts that move apart, wherever that applies)."""

    @property
    def auto_masks(self) -> bool:
        return not self.masks


def shot_name(clip_name: str, sequence: bool = True) -> str:
    """A shot name from the Movie Clip's name (``sh010_plate.1001.exr`` -> ``sh010_plate``): the extension and, for
    an image sequence, the frame number dropped; anything but letters, digits, ``_`` and ``-`` turned into ``_``. It
    names the farm's jobs and tasks."""
    stem = re.sub(r"\.[A-Za-z0-9]{2,5}$", "", clip_name.strip())
    if sequence:
        stem = re.sub(r"[._](#+|[0-9]+)$", "", stem) or stem
    name = re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_-")[:SHOT_NAME_MAX].rstrip("_-")
    return name or FALLBACK_SHOT_NAME


def engine_colorspace(blender_name: str) -> str | None:
    """The engine's name of the plate's colour space as Blender shows it; None where the add-on knows no equivalent
    (the engine then decides by its file rules, as for a local fit)."""
    return ENGINE_COLORSPACES.get(blender_name)


def set_items(long_edge: int, overrides: str = "") -> tuple[str, ...]:
    """The fit's ``KEY=VALUE`` overrides as Fit Atlas gives them (``--set`` of ``engine_commands.set_args``)."""
    return tuple(EC.set_args(long_edge, overrides)[1::2])


def frames_value(first: int, last: int) -> str:
    """A shot's ``frames``: ``FIRST-LAST`` in the plate's numbers."""
    return f"{first}-{last}"


def shots_document(shot: FarmShot) -> dict[str, object]:
    """The shots file (``engine.contract`` ``SHOTS_*``) of the one shot: the scene's fit settings as the defaults,
    the clip's own in the shot. Paths are absolute: the farm's path mapping (Deadline) or its shared storage
    (Flamenco) must see them."""
    entry: dict[str, object] = {"name": shot.name, "plate": shot.plate}
    if shot.masks:
        entry["masks"] = list(shot.masks)
    else:
        entry["auto_masks"] = True
    if not shot.auto_parts:
        entry["auto_parts"] = False
    entry["frames"] = frames_value(shot.first, shot.last)
    if shot.colorspace:
        entry["colorspace"] = shot.colorspace
    entry["run"] = shot.run_dir
    assert set(entry) <= set(C.SHOT_KEYS)
    defaults: dict[str, object] = {"preset": shot.preset, "set": list(shot.sets)}
    if not shot.follow_flow:
        defaults["follow_flow"] = False
    return {C.SHOTS_TAG: C.SHOTS_VERSION, C.SHOTS_DEFAULTS_KEY: defaults, C.SHOTS_LIST_KEY: [entry]}


def write_shots_file(shot: FarmShot, path: str) -> str:
    """Write the shots file to ``path`` (whole or not at all: a temporary file renamed onto it); returns ``path``."""
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(shots_document(shot), fh, indent=2)
        fh.write("\n")
    os.replace(tmp, path)
    return path


def online_refusal(kind: str, online_access: bool, forced: bool) -> str:
    """Why this submission must not use the network now, in one line; '' when it may. Flamenco is reached over the
    network, so it waits for Blender's online access (``bpy.app.online_access``; ``forced`` is
    ``bpy.app.online_access_override``, Blender started with --offline-mode). An OpenJD bundle is only written to
    disk, so it is always allowed."""
    if kind != FARM_FLAMENCO or online_access:
        return ""
    alternative = "or choose the OpenJD bundle (offline) as Farm in the add-on's preferences"
    if forced:
        return (
            "Submit to Farm: Blender was started offline (--offline-mode), so nothing is sent to the Flamenco "
            f"Manager: start Blender without --offline-mode, {alternative}"
        )
    return (
        "Submit to Farm: online access is off in Blender, so nothing is sent to the Flamenco Manager: turn on "
        f"{ONLINE_ACCESS_SETTING}, {alternative}"
    )


def check_manager_url(url: str) -> str:
    """The Manager's base URL without a trailing ``/``; a UserError naming the preference when it is not one."""
    url = url.strip().rstrip("/")
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise UserError(
            f"Flamenco Manager URL {url!r} is not an http(s) address: set it in the add-on's preferences "
            f"(e.g. {DEFAULT_MANAGER_URL})"
        )
    return url


def bundle_base(settings: FarmSettings, run_dir: str, name: str) -> str:
    """Where a bundle goes before numbering: ``<bundle folder>/<shot>/openjd`` when the preference names a folder,
    else ``<Run Folder>.farm/openjd``."""
    if settings.bundle_dir:
        return os.path.join(settings.bundle_dir, name, BUNDLE_FOLDER_NAME)
    return os.path.join(RunFiles(run_dir).farm_dir, BUNDLE_FOLDER_NAME)


def fresh_bundle_dir(settings: FarmSettings, run_dir: str, name: str) -> str:
    """A bundle folder no earlier submission holds (``openjd``, ``openjd_2``, ...): a bundle already handed to
    Deadline is never overwritten."""
    return fresh_dir(bundle_base(settings, run_dir, name))


def farm_argv(python: str, settings: FarmSettings, shots_path: str, bundle_dir: str | None = None) -> list[str]:
    """``farm flamenco SHOTS --manager URL --priority N`` or ``farm openjd SHOTS --out BUNDLE``."""
    if settings.kind == FARM_FLAMENCO:
        url = check_manager_url(settings.manager_url)
        args = [shots_path, "--manager", url, "--priority", str(settings.priority)]
        return EC.engine_argv(python, C.VERB_FARM, FARM_FLAMENCO, *args)
    if settings.kind == FARM_OPENJD:
        if not bundle_dir:
            raise UserError("no folder for the OpenJD bundle")
        return EC.engine_argv(python, C.VERB_FARM, FARM_OPENJD, shots_path, "--out", bundle_dir)
    raise UserError(f"unknown farm {settings.kind!r}: choose Flamenco or OpenJD in the add-on's preferences")


class FarmJob(Job):
    """Submit to Farm: one ``engine farm`` command; its result says, in one line, what the farm got."""

    idle_text = "submitting…"

    def __init__(
        self, python: str, settings: FarmSettings, shots_path: str, log_path: str, bundle_dir: str | None = None
    ):
        self.settings = settings
        self.shots_path = shots_path
        self.bundle_dir = bundle_dir if settings.kind == FARM_OPENJD else None
        argv = farm_argv(python, settings, shots_path, self.bundle_dir)
        super().__init__([Command(settings.kind, argv)], log_path, EC.engine_env())
        #: the engine's last line: the Manager's job ids (``farm flamenco``), or the bundle folder (``farm openjd``)
        self.answer = ""

    def finish(self, result: EP.JobResult) -> EP.JobResult:
        if result.status != EP.STATUS_OK:
            return result
        self.answer = self.state.last_stdout
        if self.bundle_dir is not None:
            if not os.path.isdir(self.bundle_dir):
                return failed(result, f"the engine wrote no OpenJD bundle to {self.bundle_dir}")
            result.message = f"OpenJD bundle for Deadline Cloud: {self.bundle_dir}"
        else:
            url = self.settings.manager_url.strip().rstrip("/")
            ids = self.answer.split()  # the engine's last line: the Manager's job ids, in shot order
            jobs = f": {'job' if len(ids) == 1 else 'jobs'} {' '.join(ids)}" if ids else ""
            result.message = f"submitted to Flamenco at {url}{jobs}"
        return result
