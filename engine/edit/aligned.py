"""Which export of a run the edit layers were painted against: ``edits/aligned.json`` (torch-free).

The run's edit layers are shared by all its exports; their paint matches the mapping of the export the artist
painted on. ``fit --refine`` records that export before the refined fit is exported (unless a record is there), and
``realign`` records the export it carried the paint onto, so a second ``realign`` does nothing.
"""

from __future__ import annotations

import json
from pathlib import Path

from .. import contract as C
from ..errors import InputError
from ..io.atomic import atomic_write_text
from ..terms.export_names import EDITS_ALIGNED, EDITS_ALIGNED_TAG, EDITS_DIR


def aligned_export(run_dir: str | Path) -> str | None:
    """The export (``vNNN``) the run's edit layers were painted against, as ``edits/aligned.json`` records it;
    None when nothing is recorded. A file that cannot be read is one line."""
    try:
        return C.read_aligned_export(str(run_dir))
    except ValueError:
        path = Path(run_dir) / EDITS_DIR / EDITS_ALIGNED
        raise InputError(path, "is not an edit-alignment record", "delete it and pass realign --from vNNN") from None


def write_aligned(run_dir: str | Path, version: str, carried_from: list[str] | None = None) -> Path:
    """Record that the edit layers match export ``version`` (atomically), and ``carried_from``: the manifests of
    other fits whose paint was carried onto it (``carry``), so the same paint is never laid on twice."""
    path = Path(run_dir) / EDITS_DIR / EDITS_ALIGNED
    record: dict[str, object] = {EDITS_ALIGNED_TAG: 1, "export": version}
    if carried_from:
        record["carried_from"] = list(carried_from)
    atomic_write_text(path, json.dumps(record, indent=2))
    return path


def carried_sources(run_dir: str | Path, version: str) -> list[str]:
    """The manifests whose paint was carried onto export ``version`` of the run (``write_aligned``); [] when the
    record is of another export, or has none."""
    if aligned_export(run_dir) != version:
        return []
    data = json.loads((Path(run_dir) / EDITS_DIR / EDITS_ALIGNED).read_text(encoding="utf-8"))
    found = data.get("carried_from")
    return [str(p) for p in found] if isinstance(found, list) else []


def published_exports(run_dir: str | Path) -> list[str]:
    """The run's published exports (``v001``, ``v002``, ...: folders with a manifest), oldest first."""
    exports = Path(run_dir) / C.EXPORTS_DIR
    if not exports.is_dir():
        return []
    return sorted(p.name for p in exports.iterdir() if p.name.startswith("v") and (p / C.MANIFEST_NAME).is_file())


def record_paint_export(run_dir: str | Path) -> str | None:
    """Before a refine trains: record the export the edit layers were painted against (the newest one) unless a
    record is there already. Returns the recorded version (None: no export, so no paint to carry)."""
    recorded = aligned_export(run_dir)
    if recorded is not None:
        return recorded
    versions = published_exports(run_dir)
    if not versions:
        return None
    write_aligned(run_dir, versions[-1])
    return versions[-1]


__all__ = ["aligned_export", "carried_sources", "published_exports", "record_paint_export", "write_aligned"]
