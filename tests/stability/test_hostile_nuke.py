"""Hostile names against `engine nuke`: the written script is loaded by a real ``tclsh`` (Nuke's scripts are Tcl)
with Nuke's commands stubbed as procs that record every knob, and ``exec``, ``open`` and friends traced.

Each case is a folder or layer name holding Tcl's special characters, a newline, Nuke's frame tokens or bytes that
are not UTF-8. Every case ends one of two ways: one line naming the manifest and exit 2 with no script written, or a
script that runs nothing (no traced call, no unknown command, the ``touch`` canary never appears) and whose every
Read holds byte for byte the path it means. Either way no file but the new script changes (a digest of the whole
tree before and after).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.export.nuke import FILE_KNOB_SPECIAL, SCRIPT_DIRECTORY, NukeScriptError, nuke_script, quote
from engine.terms.cli import VERB_NUKE
from engine.terms.export_names import layer_name
from engine.terms.manifest import MANIFEST_LAYER_NAME_MAX, is_layer_name, validate_manifest
from tests.engine.fake_export import make_fake_export
from tests.engine_cli import run_cli
from tests.untouched import digest_outside

TCLSH = shutil.which("tclsh")
pytestmark = pytest.mark.skipif(TCLSH is None, reason="tclsh is not installed (apt-get install tcl): it loads the .nk")

#: What a hostile name tries to run: a file of this name in the case's folder means the script executed it.
CANARY = "CANARY"
TOUCH = f"exec touch {CANARY}"

#: The loader: Nuke's node commands record their knobs (Tcl list parsing of the body, as Nuke reads a node's
#: knob/value pairs), the stack commands are no-ops, and every command that could run or open anything is traced
#: (the trace reports, then the real command runs: a successful attack shows as the canary too). Values are printed
#: as hex of their UTF-8 bytes, so the comparison is byte for byte.
LOADER = r"""
fconfigure stdout -translation lf -encoding utf-8
set f [open [lindex $argv 0] r]
fconfigure $f -encoding utf-8
set text [read $f]
close $f
proc hex {s} { binary encode hex [encoding convertto utf-8 $s] }
proc emit {args} { puts stdout [join $args " "] }
proc node {cls body} {
    emit NODE $cls
    foreach {k v} $body { emit KNOB $cls [hex $k] [hex $v] }
}
foreach cls {Root Read Copy Premult STMap Merge2} { proc $cls {body} "node $cls \$body" }
proc version {args} { emit VERSION [hex [join $args " "]] }
proc add_layer {spec} { emit LAYER [hex $spec] }
proc stack {n} { return top }
proc push {args} { emit PUSH [hex [join $args " "]] }
proc unknown {args} { emit UNKNOWN [hex [join $args " "]] }
foreach cmd {exec open source socket load cd glob file exit interp eval uplevel subst after} {
    trace add execution $cmd enter [list apply {{cmd call op} {
        if {$::loading} { emit CALL $cmd [hex $call] }
    }} $cmd]
}
set loading 1
if {[catch {namespace eval :: $text} err]} { emit ERROR [hex $err] }
set loading 0
"""


def _load_in_tcl(script: Path, cwd: Path) -> tuple[list[tuple[str, dict[str, bytes]]], list[str]]:
    """The nodes the script makes (class, knob -> value bytes) and every other event (calls, unknown commands,
    errors), as ``tclsh`` loading it reports them."""
    loader = cwd / "loader.tcl.txt"
    loader.write_text(LOADER, encoding="utf-8")
    try:
        done = subprocess.run([TCLSH, str(loader), str(script)], cwd=cwd, capture_output=True, check=True, timeout=60)
    finally:
        loader.unlink()
    nodes: list[tuple[str, dict[str, bytes]]] = []
    events: list[str] = []
    for line in done.stdout.decode("utf-8").splitlines():
        kind, *rest = line.split(" ")
        if kind == "NODE":
            nodes.append((rest[0], {}))
        elif kind == "KNOB":
            cls, key, value = rest
            assert nodes and nodes[-1][0] == cls
            nodes[-1][1][bytes.fromhex(key).decode()] = bytes.fromhex(value)
        elif kind in ("VERSION", "PUSH", "LAYER"):  # a layer declared: its names are the UV pass's, never a path
            continue
        else:
            events.append(f"{kind} {bytes.fromhex(rest[-1]).decode('utf-8', 'replace')}")
    assert done.stderr == b"", done.stderr
    return nodes, events


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """A tiny export (two frames 6x4, two layers) whose manifest's paths are all relative, as a real export writes
    them, so the folder holding it can be renamed to anything."""
    root = tmp_path_factory.mktemp("hostile_template") / "export"
    plate = np.random.default_rng(0).random((2, 4, 6, 3)).astype(np.float32)

    def uv(t, xs, ys):
        return xs / 6, 1.0 - ys / 4, np.full(xs.shape, 0.5)

    manifest = make_fake_export(root, plate, [(uv, (4, 4)), (uv, (4, 4))])
    data = json.loads(manifest.read_text())
    data["run_dir"] = "../.."
    data["clip"]["source"] = "../../../clip"
    data["clip"]["frame_files"] = [f"../../../clip/{t:05d}.png" for t in range(2)]
    manifest.write_text(json.dumps(validate_manifest(data)))
    return root


def _case(template: Path, tmp_path: Path, folder: str) -> Path:
    """The template export copied into ``tmp_path/folder``; returns its manifest."""
    target = tmp_path / folder
    shutil.copytree(template, target)
    return target / "run" / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME


def _expected_reads(prefix: str) -> dict[str, bytes]:
    """The file knob each Read must hold for an export in folder ``prefix`` (as seen from the script's folder)."""
    return {
        "NA_Passes": f"{prefix}/run/exports/v001/passes/atlas.%05d.exr".encode(),
        "NA_Edit_Background": f"{prefix}/run/edits/Background.png".encode(),
        "NA_Edit_Foreground": f"{prefix}/run/edits/Foreground.png".encode(),
        "NA_Plate": f"{prefix}/clip/%05d.png".encode(),
    }


def _check_loaded(
    script: Path, cwd: Path, expected: dict[str, bytes], colorspace: str = "sRGB Encoded Rec.709 (sRGB)"
) -> None:
    nodes, events = _load_in_tcl(script, cwd)
    assert events == []  # no exec, open, unknown command or error
    assert not (cwd / CANARY).exists()
    reads = {knobs["name"].decode(): knobs["file"] for cls, knobs in nodes if cls == "Read"}
    assert reads == expected
    for name, file in reads.items():  # each means an existing file (frame 0 of a sequence)
        assert (script.parent / os.fsdecode(file.replace(b"%05d", b"00000"))).is_file(), name
    (root,) = [knobs for cls, knobs in nodes if cls == "Root"]
    assert root["project_directory"] == SCRIPT_DIRECTORY.encode()
    (plate,) = [knobs for cls, knobs in nodes if cls == "Read" and knobs["name"] == b"NA_Plate"]
    assert plate["colorspace"] == colorspace.encode()
    assert [cls for cls, _ in nodes].count("Read") == 4 and len(nodes) == 15


#: Folder names a script can name literally: Tcl's special characters, breaks of words, lines and commands.
LITERAL_FOLDERS = {
    "open_brace": "we{ird",
    "close_brace": "we}ird",
    "braced_command": f"a {{{TOUCH}}} b",
    "quote": f'q"uote {TOUCH}"',
    "semicolon": f"x; {TOUCH}",
    "newline": f"line\n{TOUCH}\n",
    "tab_and_cr": "t\tab\rcr",
    "control": "bell\x07\x1b",
    "unicode": "plätte_Ω_日本",
}


@pytest.mark.parametrize("folder", LITERAL_FOLDERS.values(), ids=LITERAL_FOLDERS.keys())
def test_a_hostile_folder_is_read_literally_and_runs_nothing(template, tmp_path, folder):
    manifest = _case(template, tmp_path, folder)
    script = tmp_path / "comp" / "shot.nk"
    before = digest_outside(tmp_path)
    assert run_cli(VERB_NUKE, manifest, "--out", script) == (0, [])
    _check_loaded(script, tmp_path, _expected_reads(f"../{folder}"))
    after = digest_outside(tmp_path)
    assert set(after) - set(before) == {"comp", "comp/shot.nk"} and set(before) <= set(after)
    assert all(after[k] == v for k, v in before.items())


def test_a_folder_starting_with_a_tilde_is_not_a_home_folder(template, tmp_path):
    """Nuke expands a leading ``~`` in a file name: a relative path starting with one gets ``./``."""
    manifest = _case(template, tmp_path, "~plates")
    script = tmp_path / "shot.nk"
    assert run_cli(VERB_NUKE, manifest, "--out", script) == (0, [])
    _check_loaded(script, tmp_path, _expected_reads("./~plates"))


@pytest.mark.parametrize("folder", [f"out[{TOUCH}]", "out#1 %04d $x \\"], ids=["brackets", "tokens"])
def test_a_hostile_output_folder_changes_nothing_in_the_script(template, tmp_path, folder):
    """The script's own folder never appears in it (its paths are relative, the project directory is Nuke's)."""
    manifest = _case(template, tmp_path, "plain")
    script = tmp_path / folder / "shot.nk"
    assert run_cli(VERB_NUKE, manifest, "--out", script) == (0, [])
    _check_loaded(script, tmp_path, _expected_reads("../plain"))


#: Folder names refused: Nuke reads a Read's file name through its frame tokens and its Tcl evaluation, with no
#: escape, and a script is UTF-8 text.
REFUSED_FOLDERS = {
    "brackets": (f"br[{TOUCH}]", "'[]'"),
    "dollar": ("d$env(HOME)", "'$'"),
    "backslash": ("back\\slash", "'\\\\'"),
    "hash": ("shot#1", "'#'"),
    "hash_run": ("v####", "'#'"),
    "printf": ("take%d", "'%'"),
    "printf_padded": ("take%04d", "'%'"),
    "view": ("eye%V", "'%'"),
    "not_utf8": (os.fsdecode(b"bad\xff\xfename"), "not UTF-8"),
}


@pytest.mark.parametrize("folder,said", REFUSED_FOLDERS.values(), ids=REFUSED_FOLDERS.keys())
def test_a_folder_nuke_would_misread_is_refused_in_one_line(template, tmp_path, folder, said):
    manifest = _case(template, tmp_path, folder)
    script = tmp_path / "comp" / "shot.nk"
    before = digest_outside(tmp_path)
    code, err = run_cli(VERB_NUKE, manifest, "--out", script)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1, err
    line = err[0]
    assert line.startswith(f"error: {manifest.resolve()}: the pass file path ") and said in line
    assert line.endswith("does not pass through it)") and "rename the folder or file" in line
    assert digest_outside(tmp_path) == before  # no script, no folder for it, nothing else touched
    assert not (tmp_path / CANARY).exists()


def test_a_plate_file_name_with_a_frame_token_is_refused(template, tmp_path):
    """The plate's own file names, not only its folders: ``#`` there would be a second frame token."""
    manifest = _case(template, tmp_path, "plain")
    clip = tmp_path / "plain" / "clip"
    data = json.loads(manifest.read_text())
    for t in range(2):
        (clip / f"{t:05d}.png").rename(clip / f"shot#a.{t:05d}.png")
    data["clip"]["frame_files"] = [f"../../../clip/shot#a.{t:05d}.png" for t in range(2)]
    manifest.write_text(json.dumps(data))
    code, err = run_cli(VERB_NUKE, manifest, "--out", tmp_path / "shot.nk")
    assert code == C.EXIT_BAD_INPUT and len(err) == 1
    assert "the plate frame path 'plain/clip/shot#a.00000.png' holds '#'" in err[0]
    assert not (tmp_path / "shot.nk").exists()


HOSTILE_LAYER_NAMES = [
    f"Fg[{TOUCH}]",
    f"Fg\n{TOUCH}",
    f"Fg;{TOUCH}",
    "Fg$x",
    "Fg{",
    "Fg}",
    'Fg"',
    "Fg\\",
    "Fg#1",
    "Fg%04d",
    "Fg.R",
    "Fg ground",
    "Fördergrund",
    "9Lives",
    "F" * (MANIFEST_LAYER_NAME_MAX + 1),
]


@pytest.mark.parametrize("name", HOSTILE_LAYER_NAMES)
def test_a_layer_name_that_is_not_plain_is_refused_at_load(template, tmp_path, name):
    """A hand-edited manifest's layer name never reaches a script: `engine nuke` stops at loading it, in one line
    naming the manifest, before any file is written."""
    manifest = _case(template, tmp_path, "plain")
    data = json.loads(manifest.read_text())
    data["layers"][1]["name"] = name
    manifest.write_text(json.dumps(data))
    script = tmp_path / "shot.nk"
    before = digest_outside(tmp_path)
    code, err = run_cli(VERB_NUKE, manifest, "--out", script)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1, err
    assert err[0].startswith(f"error: {manifest.resolve()}: manifest layer 1 name ")
    assert "is not a plain name (letters, digits and _" in err[0] and err[0].endswith("export RUN_DIR` again")
    assert digest_outside(tmp_path) == before
    with pytest.raises(C.ManifestError, match="not a plain name"):
        validate_manifest(data)
    with pytest.raises(NukeScriptError, match="not a plain name"):  # a manifest handed over as a dict, unchecked
        nuke_script(data, str(manifest))


def test_the_engines_own_layer_names_are_plain():
    for count in range(1, 9):
        for i in range(count):
            assert is_layer_name(layer_name(i, count))
    assert is_layer_name("F" * MANIFEST_LAYER_NAME_MAX)
    assert not is_layer_name("F" * (MANIFEST_LAYER_NAME_MAX + 1)) and not is_layer_name("")


def test_a_hostile_colour_space_name_is_one_literal_knob(template, tmp_path):
    """The plate's colour space name (any printable text with an OCIO config) reaches the Read as it is."""
    manifest = _case(template, tmp_path, "plain")
    data = json.loads(manifest.read_text())
    name = f'lin [{TOUCH}] $x {{y}} "z" \\w; }}'
    data["clip"].update(colorspace=name, colour_config="ocio://default")
    manifest.write_text(json.dumps(validate_manifest(data)))
    script = tmp_path / "comp" / "shot.nk"
    assert run_cli(VERB_NUKE, manifest, "--out", script) == (0, [])
    _check_loaded(script, tmp_path, _expected_reads("../plain"), colorspace=name)


QUOTED_VALUES = [
    "",
    "plain",
    "a b",
    '\\"[]${};',
    "}{",
    "\\",
    "end\\",
    "\n\r\t\x00\x1f\x7f",
    f"[{TOUCH}]",
    "$env(HOME)",
    "ü日本😀",
    "#comment",
]


def test_quote_gives_tcl_back_every_value_exactly(tmp_path):
    """Each value quoted as a knob value, then read back by Tcl's own list parser (how a node's body is split) and
    as a command's word (where substitution would run): the same bytes, nothing run."""
    lines = [f"lappend words {quote(v)}" for v in QUOTED_VALUES]
    body = "\n".join(f" k{i} {quote(v)}" for i, v in enumerate(QUOTED_VALUES))
    script = tmp_path / "values.tcl.txt"
    script.write_text(
        "fconfigure stdout -translation lf -encoding utf-8\nset words {}\n" + "\n".join(lines) + "\n"
        f"set body {{\n{body}\n}}\n"
        "foreach w $words { puts [binary encode hex [encoding convertto utf-8 $w]] }\n"
        "foreach {k v} $body { puts [binary encode hex [encoding convertto utf-8 $v]] }\n",
        encoding="utf-8",
    )
    done = subprocess.run(
        [TCLSH, "-encoding", "utf-8", str(script)], cwd=tmp_path, capture_output=True, check=True, timeout=60
    )
    got = [bytes.fromhex(h).decode("utf-8") for h in done.stdout.decode().splitlines()]
    assert got == QUOTED_VALUES * 2
    assert not (tmp_path / CANARY).exists()
    assert all("\n" not in quote(v) for v in QUOTED_VALUES)  # one knob, one line
    assert set(FILE_KNOB_SPECIAL) == set("#%[]$\\")
