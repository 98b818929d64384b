"""The plate a manifest names: relative to the manifest first; the paths kept as at export only where the relative
ones name nothing and those do (a run folder moved alone); a sequence pattern counts as there when its folder is."""

from __future__ import annotations

from engine import contract as C


def _clip(source: str, files: list[str], absolute: str | None, files_absolute: list[str] | None) -> dict:
    clip: dict = {"source": source, "frame_files": files}
    if absolute is not None:
        clip["source_absolute"] = absolute
    if files_absolute is not None:
        clip["frame_files_absolute"] = files_absolute
    return clip


def test_the_relative_plate_wins_while_it_is_there(tmp_path):
    run, old = tmp_path / "run" / "exports" / "v001", tmp_path / "old"
    (tmp_path / "clip").mkdir(parents=True)
    (tmp_path / "clip" / "0001.png").write_bytes(b"x")
    old.mkdir()
    (old / "0001.png").write_bytes(b"y")
    manifest = str(run / C.MANIFEST_NAME)
    clip = _clip("../../../clip", ["../../../clip/0001.png"], str(old), [str(old / "0001.png")])
    assert C.resolve_plate_path(manifest, clip) == str(tmp_path / "clip")
    assert C.resolve_plate_path(manifest, clip, 0) == str(tmp_path / "clip" / "0001.png")


def test_the_path_at_export_where_the_relative_one_names_nothing(tmp_path):
    manifest = str(tmp_path / "moved" / "run" / "exports" / "v001" / C.MANIFEST_NAME)
    plate = tmp_path / "plate"
    plate.mkdir()
    (plate / "a.1001.exr").write_bytes(b"x")
    pattern = str(plate / "a.####.exr")
    clip = _clip("../../../plate/a.####.exr", ["../../../plate/a.1001.exr"], pattern, [str(plate / "a.1001.exr")])
    assert C.resolve_plate_path(manifest, clip) == pattern  # a pattern: its folder is there
    assert C.resolve_plate_path(manifest, clip, 0) == str(plate / "a.1001.exr")
    # neither there: the relative one, which the reader names in its error
    gone = _clip("../../../plate/a.####.exr", ["../../../plate/a.1001.exr"], str(tmp_path / "no" / "a.####.exr"),
                 [str(tmp_path / "no" / "a.1001.exr")])  # fmt: skip
    assert C.resolve_plate_path(manifest, gone, 0) == str(tmp_path / "moved" / "plate" / "a.1001.exr")
    # a list that does not match the frames, or none at all (an older manifest): the relative one
    short = _clip("../../../plate", ["../../../plate/a.1001.exr"], None, [])
    assert C.resolve_plate_path(manifest, short, 0) == str(tmp_path / "moved" / "plate" / "a.1001.exr")
    assert C.resolve_plate_path(manifest, _clip("../../../plate", [], None, None)) == str(tmp_path / "moved" / "plate")
