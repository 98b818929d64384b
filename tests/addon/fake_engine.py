"""A stand-in for ``python -m engine`` in the add-on tests: speaks the progress protocol and misbehaves on
request (FAKE_ENGINE_MODE = ok | crash | traceback | hang | bad_input | parts). Run as a script: argv[1:] are
what the engine would get after ``-m engine`` (the wrapper drops those two)."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from engine import contract as C
from engine.terms.protocol import EVENT_CANCELLED, progress_line
from engine.terms.versions import ENGINE_VERSION


def say(event: str, **fields) -> None:
    print(progress_line(event, **fields), flush=True)


def farm(argv: list[str], mode: str) -> int:
    """``farm openjd SHOTS --out DIR`` (a bundle's two files) or ``farm flamenco SHOTS --manager URL`` (a job id)."""
    if mode == "bad_input":
        print(f'error: {argv[1]}: no shot has a plate — add "plate" to each shot', file=sys.stderr)
        return C.EXIT_BAD_INPUT
    if argv[0] == C.FARM_OPENJD:
        out = Path(argv[argv.index("--out") + 1])
        out.mkdir(parents=True)
        (out / "template.json").write_text('{"specificationVersion": "jobtemplate-2023-09"}\n')
        (out / "parameter_values.json").write_text('{"parameterValues": []}\n')
        print(out)
        return 0
    print("fake-0001")
    return 0


def main(argv: list[str]) -> int:
    mode = os.environ.get("FAKE_ENGINE_MODE", "ok")
    if argv and argv[0] == "--version":
        print(f"neural-atlas engine {ENGINE_VERSION} (fake)")
        return 0
    verb = argv[0]
    if verb == C.VERB_FARM:
        return farm(argv[1:], mode)
    out = argv[argv.index("--out") + 1] if "--out" in argv else (argv[1] if len(argv) > 1 else "")
    if verb == C.VERB_EXPORT:
        from fake_export import make_export

        # a scribble fit splits its one object: Background, Foreground1, Foreground2
        fit_argv = Path(out) / "fake_fit_argv.txt"
        scribbled = fit_argv.exists() and C.SCRIBBLE_ARG in fit_argv.read_text().split("\n")
        split = (Path(out) / "fake_parts.txt").exists()  # parts mode: the search split the object in two
        foregrounds = 2 if scribbled or split else 1
        manifest = make_export(Path(out).parent / (Path(out).name + ".fake_export"), foregrounds=foregrounds)
        say(C.EVENT_EXPORTED, manifest=str(manifest))
        print(manifest)
        return 0
    if verb == C.VERB_REALIGN:  # the edit layers are left as they are; the newest (fake) export is named
        (Path(out) / "fake_realign_argv.txt").write_text("\n".join(argv))
        print(Path(out).parent / (Path(out).name + ".fake_export") / "run" / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME)
        return 0
    if verb == C.VERB_ESTIMATE:
        import json

        rows = [{"preset": "draft", "total_seconds": 61.0, "expected_psnr": 25.7, "minutes": 1.0}]
        print("timing presets…", flush=True)
        for done in (0, 1):  # as `estimate --json` reports each preset timed
            left = None if done == 0 else 0.0
            say(C.EVENT_JOB, stage="estimate", done=done, total=1, stage_eta=left, job_fraction=0.05 + 0.95 * done,
                job_eta=left)  # fmt: skip
        print(json.dumps({C.ESTIMATE_TAG: 1, "presets": rows, "argv": argv}), flush=True)
        return 0
    print("tqdm-like noise 10%|#", flush=True)
    if mode == "parts":  # as `fit` says it: the flow's last pair, the search, its finding (it split the object)
        say(C.EVENT_JOB, stage="flow", done=4, total=4, stage_eta=0.0, job_fraction=0.1, job_eta=None)
        say(C.EVENT_STAGE, stage=C.VERB_PARTS, message=f"looking for parts that move apart ({out}/parts)")
        time.sleep(0.3)
        found = f"2 parts that move apart, strokes on 5 frame(s) (0, 1, 2, 3, 4) ({out}/parts)"
        say(C.EVENT_STAGE, stage=C.VERB_PARTS, message=found, **{C.STAGE_PARTS_FIELD: 2})
        time.sleep(0.3)
        Path(out).mkdir(parents=True, exist_ok=True)
        (Path(out) / "fake_parts.txt").write_text(found)
    say(C.EVENT_STAGE, stage="train", message="training")
    if mode == "bad_input":
        print(f"error: {out}/masks: mask folder does not exist — pass the folder that holds the masks", file=sys.stderr)
        return C.EXIT_BAD_INPUT
    total = 1000 if mode == "hang" else 10
    cancelled = []
    signal.signal(signal.SIGTERM, lambda *_: cancelled.append(True))
    step = 0
    while True:
        step += 1
        say(C.EVENT_PROGRESS, step=step, total=total, psnr=20.0 + step, elapsed=0.1 * step, eta=0.1 * (total - step))
        if mode == "parts":  # as `fit` says it: the training stage's count, and the whole job's
            say(C.EVENT_JOB, stage="train", done=step, total=total, stage_eta=0.05 * (total - step),
                job_fraction=0.1 + 0.8 * step / total, job_eta=0.05 * (total - step))  # fmt: skip
        if mode == "crash" and step == 2:
            os.kill(os.getpid(), signal.SIGKILL)
        if mode == "traceback" and step == 2:
            raise RuntimeError("simulated engine bug")
        if cancelled:
            Path(out).mkdir(parents=True, exist_ok=True)
            (Path(out) / C.RUN_CHECKPOINT).write_text("fake")
            say(EVENT_CANCELLED, step=step, checkpoint=str(Path(out) / C.RUN_CHECKPOINT))
            return C.EXIT_CANCELLED
        if mode != "hang" and step >= total:
            break
        time.sleep(0.05)
    Path(out).mkdir(parents=True, exist_ok=True)
    (Path(out) / "fake_fit_argv.txt").write_text("\n".join(argv))
    say(C.EVENT_DONE, metrics={"psnr": 30.0, "steps": total})
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
