"""The plan as an Open Job Description job bundle (``jobtemplate-2023-09``), for AWS Deadline Cloud and ``openjd run``.

A bundle is a folder of three files (JSON, which every OpenJD and Deadline Cloud reader takes as it takes YAML):

- ``template.json``: one step per task kind per shot (``sh010-fit``, ``sh010-passes``, ...), the chunks of a kind as
  the step's tasks over a ``Frames`` task parameter, the plan's dependencies as step dependencies, and, on the
  steps that want one, a host requirement of a GPU (``amount.worker.gpu``; ``--no-gpu`` leaves it out for a
  farm of CPU hosts). Every path is a job parameter of type PATH: plates and mask folders ``dataFlow: IN``, run
  folders ``INOUT`` (the fit writes them, every later step reads them), render folders ``OUT``, so Deadline Cloud maps
  them onto each worker's mounts and its job attachments upload the inputs and download the outputs. The worker's
  engine Python is the ``EnginePython`` parameter, and ``EnginePath`` (the folder holding ``engine/``, empty when the
  engine is installed into that Python) is put in front of the worker's ``PYTHONPATH`` (an ``openjd_env`` message of
  the job environment's onEnter: a template's variables can only replace a value). The same environment sets
  ``terms.protocol.OPENJD_PROGRESS_ENV``, so every task prints ``openjd_progress`` and ``openjd_status`` messages: the
  farm's monitor shows each task's progress and stage.
- ``parameter_values.json``: those parameters' values on the submitting machine (Deadline Cloud's format).
- ``asset_references.json``: the same inputs and outputs as Deadline Cloud's asset references.
- ``job_parameters.json``: the parameter values again, as ``openjd run -p file://BUNDLE/job_parameters.json``
  reads them, to run the bundle on this machine.

The step commands are the plan's command lines with each path replaced by its parameter (``farm plan`` shows
them); the task parameter substitutes the chunk's frames. ``openjd run`` does not look at host requirements, so a
bundle with GPU requirements still runs on a CPU host locally.

OpenJD evaluates ``{{...}}`` in every string of a template and has no escape for it, but never evaluates a
parameter's value. So a literal of the plan that holds a brace (a file named ``{{x}}.####.exr``, a colour space,
the job's name) is not written into the template: it becomes a STRING job parameter (``Text1``, ...) whose value is
that literal, and the template names the parameter. Every template is checked with the OpenJD model library (what
``openjd check`` and Deadline Cloud run) together with its parameter values before anything is written, so a bundle
they would refuse is never written.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import unicodedata
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import contract as C
from ..errors import InputError
from ..io.atomic import atomic_write_text
from ..terms.protocol import OPENJD_PROGRESS_ENV, progress_line
from .plan import CHUNKED_KINDS, Plan, ShotPlan, Task

SPECIFICATION_VERSION = "jobtemplate-2023-09"
TEMPLATE_FILE = "template.json"
PARAMETER_VALUES_FILE = "parameter_values.json"
ASSET_REFERENCES_FILE = "asset_references.json"
#: The same values as ``openjd run -p file://BUNDLE/job_parameters.json`` takes them (a plain name: value map).
JOB_PARAMETERS_FILE = "job_parameters.json"
#: The job parameters every bundle has.
PYTHON_PARAMETER = "EnginePython"
ENGINE_PATH_PARAMETER = "EnginePath"
#: The task parameter of a chunked step: its tasks' frame ranges ("1001-1050").
FRAMES_PARAMETER = "Frames"
#: The job environment's onEnter: prints ``openjd_env: PYTHONPATH=<EnginePath><pathsep><the worker's PYTHONPATH>``
#: (nothing when EnginePath is empty), run by the engine's Python so the separator is the worker's. No braces: OpenJD
#: would read them as an expression.
PREPEND_PYTHONPATH = (
    "import os, sys; new, old = sys.argv[1], os.environ.get('PYTHONPATH', ''); "
    "print('openjd_env: PYTHONPATH=' + os.pathsep.join(p for p in (new, old) if p)) if new else None"
)
#: The host requirement of the fit, atlases and passes steps.
GPU_AMOUNT = "amount.worker.gpu"
DEFAULT_PYTHON = "python3"
_IDENTIFIER_MAX = 64
#: The job parameters that carry the plan's literals holding a brace: Text1, Text2, ...
TEXT_PARAMETER_PREFIX = "Text"
#: OpenJD's limits (jobtemplate-2023-09): tasks of a step's list-form task parameter, characters of a
#: parameter's value, characters of a job name.
MAX_STEP_TASKS = 1024
MAX_PARAMETER_VALUE = 1024
MAX_JOB_NAME = 128
#: What OpenJD would read as the start or end of an expression in a template string.
_BRACES = re.compile(r"[{}]")


@dataclass
class _PathParameter:
    name: str
    value: str
    object_type: str  # FILE | DIRECTORY
    data_flow: str  # IN | OUT | INOUT
    description: str

    def definition(self) -> dict[str, Any]:
        """No default: OpenJD takes a PATH default only relative to the template's folder and inside it, and
        the plan's paths are neither (parameter_values.json gives them)."""
        return {
            "name": self.name,
            "type": "PATH",
            "objectType": self.object_type,
            "dataFlow": self.data_flow,
            "description": self.description,
        }


@dataclass
class _Parameters:
    """The job's PATH parameters and its literal-carrying STRING parameters, and how to write an argument of the
    plan through them."""

    paths: list[_PathParameter] = field(default_factory=list)
    texts: dict[str, str] = field(default_factory=dict)
    """Literal value -> its STRING parameter's name, in order of first use."""

    def literal(self, text: str) -> str:
        """``text`` as a template string that resolves to exactly ``text``: itself, or, when it holds a brace
        (which OpenJD would read as an expression and has no escape for), a parameter holding it."""
        if not _BRACES.search(text):
            return text
        name = self.texts.get(text)
        if name is None:
            name = self.texts[text] = f"{TEXT_PARAMETER_PREFIX}{len(self.texts) + 1}"
        return f"{{{{Param.{name}}}}}"

    def add(self, prefix: str, shot: str, value: str, object_type: str, data_flow: str, description: str) -> None:
        name = _identifier(f"{prefix}_{shot}")
        taken = {p.name for p in self.paths}
        if name in taken:
            name = _identifier(f"{prefix}_{len(self.paths) + 1}")
        self.paths.append(_PathParameter(name, value, object_type, data_flow, description))

    def substitute(self, arg: str) -> str:
        """``arg`` with the longest parameter path it is, or starts with, written as that parameter."""
        for p in sorted(self.paths, key=lambda p: len(p.value), reverse=True):
            if arg == p.value:
                return f"{{{{Param.{p.name}}}}}"
            if arg.startswith(p.value.rstrip(os.sep) + os.sep):
                rest = arg[len(p.value.rstrip(os.sep)) + 1 :]
                return f"{{{{Param.{p.name}}}}}/{self.literal(rest.replace(os.sep, '/'))}"
        return self.literal(arg)


def write_bundle(
    plan: Plan,
    shot_plans: list[ShotPlan],
    out: str | Path,
    *,
    name: str = "Neural Atlas",
    gpu: bool = True,
    python: str = DEFAULT_PYTHON,
    engine_path: str = "",
) -> list[Path]:
    """Write the bundle of ``plan`` into the folder ``out`` (created; the bundle's files are replaced, each
    atomically). Returns the files written."""
    folder = Path(out)
    if folder.exists() and not folder.is_dir():
        raise InputError(folder, "is a file, not a folder", "pass a folder for the bundle with --out")
    params = _parameters(shot_plans)
    template = job_template(plan, params, name=name, gpu=gpu, python=python, engine_path=engine_path)
    values = {
        PYTHON_PARAMETER: python,
        ENGINE_PATH_PARAMETER: engine_path,
        **{p.name: p.value for p in params.paths},
        **{parameter: text for text, parameter in params.texts.items()},
    }
    check_bundle(template, values)
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for file, data in (
        (TEMPLATE_FILE, template),
        (PARAMETER_VALUES_FILE, {"parameterValues": [{"name": k, "value": v} for k, v in values.items()]}),
        (JOB_PARAMETERS_FILE, values),
        (ASSET_REFERENCES_FILE, asset_references(params)),
    ):
        path = folder / file
        atomic_write_text(path, json.dumps(data, indent=2) + "\n")
        files.append(path)
    return files


def job_template(
    plan: Plan, params: _Parameters, *, name: str, gpu: bool, python: str, engine_path: str
) -> dict[str, Any]:
    """The job template: the parameters, an environment that puts the engine on PYTHONPATH, and the steps."""
    steps = {task.id: step_name(task) for task in plan.tasks}
    job_name = params.literal(_job_name(name))
    built = [_step(step, tasks, steps, params, gpu) for step, tasks in steps_of(plan)]
    definitions: list[dict[str, Any]] = [
        {
            "name": PYTHON_PARAMETER,
            "type": "STRING",
            "default": python,
            "description": "the engine's Python on the workers (it runs `python -m engine ...`)",
        },
        {
            "name": ENGINE_PATH_PARAMETER,
            "type": "STRING",
            "default": engine_path,
            "minLength": 0,
            "description": "the folder holding engine/ on the workers (PYTHONPATH); empty when the engine is installed",
        },
        *(p.definition() for p in params.paths),
        *(
            {
                "name": parameter,
                "type": "STRING",
                "minLength": 0,
                "description": "a literal of the plan (it holds a brace)",
            }
            for parameter in params.texts.values()
        ),
    ]
    return {
        "specificationVersion": SPECIFICATION_VERSION,
        "name": job_name,
        "parameterDefinitions": definitions,
        "jobEnvironments": [
            {
                "name": "NeuralAtlasEngine",
                "description": "the engine's package in front of the workers' Python path; progress for the farm",
                "script": {
                    "actions": {
                        "onEnter": {
                            "command": f"{{{{Param.{PYTHON_PARAMETER}}}}}",
                            "args": ["-c", PREPEND_PYTHONPATH, f"{{{{Param.{ENGINE_PATH_PARAMETER}}}}}"],
                        }
                    }
                },
                "variables": {OPENJD_PROGRESS_ENV: "1"},
            }
        ],
        "steps": built,
    }


def _job_name(name: str) -> str:
    """The job's name, at most MAX_JOB_NAME characters; a control character (a newline) is refused: OpenJD and
    Deadline Cloud take none in a name."""
    if any(unicodedata.category(c) == "Cc" for c in name):
        raise InputError(
            None,
            f"the job name {name!r} holds a control character (a newline or a tab)",
            "give --name a name on one line (the default is the shots file's name)",
        )
    return name[:MAX_JOB_NAME]


def check_bundle(template: dict[str, Any], values: dict[str, str]) -> None:
    """Check ``template`` with ``values`` as ``openjd check`` and ``openjd run`` do (the OpenJD model library):
    a bundle the farm would refuse is refused here, in one line, before it is written."""
    try:
        from openjd.model import (
            DecodeValidationError,
            ParameterValue,
            ParameterValueType,
            create_job,
            decode_job_template,
        )
    except ImportError as exc:
        raise InputError(
            None,
            f"farm openjd needs the OpenJD model library ({exc})",
            'install the farm extra: pip install "neural-atlas[farm]"',
        ) from None
    for name, value in values.items():
        if len(value) > MAX_PARAMETER_VALUE:
            raise InputError(
                value[:80] + "...",
                f"is {len(value)} characters: OpenJD takes at most {MAX_PARAMETER_VALUE} in the value of {name}",
                "move the plate, masks, run or render folder to a shorter path",
            )
    kinds = {p["name"]: p["type"] for p in template["parameterDefinitions"]}
    try:
        job_template = decode_job_template(template=template)
        create_job(
            job_template=job_template,
            job_parameter_values={
                k: ParameterValue(type=ParameterValueType(kinds[k]), value=v) for k, v in values.items()
            },
        )
    except (DecodeValidationError, ValueError) as exc:
        problem = " ".join(str(exc).split())
        raise InputError(
            None,
            f"the OpenJD bundle would be refused ({problem[:400]})",
            "rename what the message names, or report it with the shots file",
        ) from None


def step_name(task: Task) -> str:
    """The OpenJD step a task belongs to: one per task kind per shot."""
    return f"{task.shot}-{task.kind}"


def steps_of(plan: Plan) -> list[tuple[str, list[Task]]]:
    """The plan's tasks grouped into steps, in the plan's order (dependencies first)."""
    steps: dict[str, list[Task]] = {}
    for task in plan.tasks:
        steps.setdefault(step_name(task), []).append(task)
    return list(steps.items())


def _step(step: str, tasks: list[Task], steps: dict[str, str], params: _Parameters, gpu: bool) -> dict[str, Any]:
    """One step: ``steps`` names each task's step by task id (a dependency's step)."""
    first = tasks[0]
    args = _templated_args(step, tasks, params)
    body: dict[str, Any] = {"name": step}
    if first.kind in CHUNKED_KINDS:
        ranges = [f"{t.frames[0]}-{t.frames[1]}" for t in tasks if t.frames is not None]
        if len(ranges) > MAX_STEP_TASKS:
            key = "export_chunk" if first.kind != "render" else "render_chunk"
            frames = sum(t.frames[1] - t.frames[0] + 1 for t in tasks if t.frames is not None)
            raise InputError(
                None,
                f"shot {first.shot}: {len(ranges)} {first.kind} chunks, more than the {MAX_STEP_TASKS} tasks OpenJD "
                "takes in a step",
                f"give the shot {key} = {-(-frames // MAX_STEP_TASKS)} or more",
            )
        body["parameterSpace"] = {
            "taskParameterDefinitions": [{"name": FRAMES_PARAMETER, "type": "STRING", "range": ranges}]
        }
    depends = sorted({steps[d] for t in tasks for d in t.depends} - {step})
    if depends:
        body["dependencies"] = [{"dependsOn": d} for d in depends]
    if gpu and first.accelerator:
        body["hostRequirements"] = {"amounts": [{"name": GPU_AMOUNT, "min": 1}]}
    body["script"] = {
        "actions": {
            "onRun": {
                "command": f"{{{{Param.{PYTHON_PARAMETER}}}}}",
                "args": ["-m", C.CLI_MODULE, *args],
                # SIGTERM first, then time to checkpoint: a preempted fit or chunk keeps its work for the retry
                "cancelation": {"mode": "NOTIFY_THEN_TERMINATE", "notifyPeriodInSeconds": 60},
            }
        }
    }
    return body


def _templated_args(step: str, tasks: list[Task], params: _Parameters) -> list[str]:
    """The step's one command line: the tasks' argv with paths as parameters and a chunk's frames as the task
    parameter. Every task of the step must give the same line (else the plan does not fit one step)."""
    lines = set()
    for task in tasks:
        args = [params.substitute(a) for a in task.args]
        if task.kind in CHUNKED_KINDS:
            at = args.index("--frames") + 1
            args[at] = f"{{{{Task.Param.{FRAMES_PARAMETER}}}}}"
        lines.add(tuple(args))
    if len(lines) != 1:
        raise ValueError(f"the tasks of step {step} differ beyond their frames: {sorted(lines)}")
    return list(lines.pop())


def _parameters(shot_plans: Iterable[ShotPlan]) -> _Parameters:
    params = _Parameters()
    for sp in shot_plans:
        shot = sp.shot
        plate, kind = shot.plate, "DIRECTORY" if os.path.isdir(shot.plate) else "FILE"
        if not os.path.exists(plate):  # a sequence pattern: its folder is the input, the pattern stays in the args
            plate, kind = os.path.dirname(plate), "DIRECTORY"
        params.add("Plate", shot.name, plate, kind, "IN", f"shot {shot.name}: the plate")
        for i, mask in enumerate(shot.masks):
            params.add(f"Mask{i + 1}", shot.name, mask, "DIRECTORY", "IN", f"shot {shot.name}: mask folder {i + 1}")
        params.add("Run", shot.name, shot.run, "DIRECTORY", "INOUT", f"shot {shot.name}: the run folder")
        if shot.render is not None:
            params.add("Render", shot.name, shot.render, "DIRECTORY", "OUT", f"shot {shot.name}: rendered frames")
    return params


def asset_references(params: _Parameters) -> dict[str, Any]:
    """Deadline Cloud's asset references: the input files and folders to upload (a run folder that exists already,
    e.g. a fit to continue, among them), the output folders to fetch (run and render folders)."""
    inputs = [p for p in params.paths if p.data_flow == "IN" or (p.data_flow == "INOUT" and os.path.isdir(p.value))]
    return {
        "assetReferences": {
            "inputs": {
                "filenames": [p.value for p in inputs if p.object_type == "FILE"],
                "directories": [p.value for p in inputs if p.object_type == "DIRECTORY"],
            },
            "outputs": {"directories": [p.value for p in params.paths if p.data_flow in ("OUT", "INOUT")]},
            "referencedPaths": [],
        }
    }


def _identifier(text: str) -> str:
    """An OpenJD identifier: letters, digits and _, not starting with a digit, at most 64 characters."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", text)
    if not re.match(r"[A-Za-z_]", name):
        name = f"P{name}"
    return name[:_IDENTIFIER_MAX]


def add_openjd_parser(sub: argparse._SubParsersAction, shots_help: str) -> argparse.ArgumentParser:
    """The ``openjd`` sub-command of ``farm``."""
    oj: argparse.ArgumentParser = sub.add_parser(
        C.FARM_OPENJD,
        help="write an Open Job Description bundle (AWS Deadline Cloud; `openjd run`)",
        description="Write BUNDLE_DIR/template.json, parameter_values.json and asset_references.json (Deadline "
        "Cloud's job bundle) and job_parameters.json (`openjd run BUNDLE_DIR/template.json -p "
        "file://BUNDLE_DIR/job_parameters.json`). The last line printed is the template's path.",
    )
    oj.add_argument("shots", metavar="SHOTS", help=shots_help)
    oj.add_argument("--out", required=True, metavar="BUNDLE_DIR", help="the bundle's folder (created)")
    oj.add_argument(
        "--engine-python",
        default=sys.executable,
        metavar="PYTHON",
        help="the engine's Python on the workers (default: this one; the EnginePython job parameter)",
    )
    oj.add_argument(
        "--engine-path",
        default=str(Path(__file__).resolve().parents[2]),
        metavar="DIR",
        help="the folder holding engine/ on the workers, put on PYTHONPATH (default: this engine's; '' when the "
        "engine is installed in the workers' Python)",
    )
    oj.add_argument("--no-gpu", action="store_true", help="no GPU host requirement on the fit and export steps")
    oj.add_argument("--name", default=None, help="the job's name (default: the shots file's name)")
    return oj


def run_openjd(args: argparse.Namespace, plan: Plan, shot_plans: list[ShotPlan], shots_path: Path) -> list[Path]:
    """``farm openjd``: the bundle of ``plan`` written (its files, the template first), a progress line per shot."""
    files = write_bundle(
        plan,
        shot_plans,
        args.out,
        name=args.name or f"Neural Atlas {shots_path.stem}",
        gpu=not args.no_gpu,
        python=args.engine_python,
        engine_path=args.engine_path,
    )
    for sp in shot_plans:
        name, count = sp.shot.name, len(plan.shot_tasks(sp.shot.name))
        message = f"{name}: {count} tasks, export {sp.version}"
        print(progress_line(C.EVENT_STAGE, stage=C.VERB_FARM, shot=name, tasks=count, message=message))
    return files


__all__ = [
    "TEMPLATE_FILE",
    "add_openjd_parser",
    "job_template",
    "run_openjd",
    "step_name",
    "steps_of",
    "write_bundle",
]
