// SPDX-License-Identifier: GPL-3.0-or-later
//
// Neural Atlas job type for Flamenco 3.x: one job per shot, one Flamenco task per task of the engine's farm plan.
//
// Install: copy this file into the `scripts` folder beside the `flamenco-manager` executable and restart the
// Manager; the job type's name is the file name without `.js`: "neural-atlas". Jobs of this type are submitted by
// `python -m engine farm flamenco SHOTS --manager URL` (the file itself: `python -m engine farm flamenco
// --job-type-out DIR`).
//
// Why the plan travels as one JSON setting: the engine computes every task's exact arguments and dependencies at
// submit time (engine/farm/plan.py, the same plan the OpenJD and Dask back ends run), and Flamenco job settings
// cannot hold nested values. This script only maps the plan onto Flamenco's tasks, so every farm runs the very
// same command lines; it never builds arguments of its own.
//
// Each task runs one `exec` command:  {neural_atlas_python} -m MODULE ARGS... (MODULE: the plan's "module", the
// engine's import name on the submitting machine: `engine` from a checkout or the extension, `neural_atlas` from
// the wheel; "engine" when a plan has none)
//   - `{neural_atlas_python}` is a Manager variable (flamenco-manager.yaml, `variables:`), one value per worker
//     platform: the Python in which `python -m engine` runs on that worker.
//   - Task types: "neural-atlas" for tasks that run anywhere (masks, export publish, render, preview) and
//     "neural-atlas-gpu" for the ones that want an accelerator (fit, atlases, passes). A worker only gets the
//     task types listed in its flamenco-worker.yaml `task_types`: GPU workers list both, CPU-only workers list
//     "neural-atlas".
//   - Paths: the submitter rewrites every argument that starts with the submitter-platform value of one of the
//     Manager's two-way variables into `{variable}/rest` (what Flamenco itself does to whole job settings); when a
//     worker receives the task, the Manager expands `{variable}` to that worker's platform value. Arguments that
//     start with the Manager platform's value of a two-way variable are also remapped by the Manager.
//
// Retries are safe: every engine command of the plan is idempotent or resumes (a fit continues its checkpoint,
// finished export chunks and rendered frames are kept), so a task Flamenco requeues after a worker was lost picks
// up where it stopped.

const PLAN_TAG = "neural_atlas_flamenco_plan";
const PLAN_VERSION = 1;
const PYTHON_EXE = "{neural_atlas_python}";
const TASK_TYPE = "neural-atlas";
const TASK_TYPE_GPU = "neural-atlas-gpu";
const TASK_KINDS = ["masks", "fit", "atlases", "passes", "publish", "render", "preview"];
const RESUBMIT = "submit the shot again with `python -m engine farm flamenco SHOTS --manager URL`";

const JOB_TYPE = {
    label: "Neural Atlas",
    description: "Fit, export and render one shot with the Neural Atlas engine",
    settings: [
        { key: "shot", type: "string", required: true, visible: "web", description: "The shot's name" },
        {
            key: "plan", type: "string", required: true, visible: "hidden",
            description: "The shot's tasks as computed by the engine at submit time (JSON)",
        },
    ],
};

function compileJob(job) {
    const settings = job.settings;
    const plan = parsePlan(settings.plan, settings.shot);
    const authored = new Map();
    for (const step of plan.tasks) {
        const task = author.Task(step.id, step.accelerator ? TASK_TYPE_GPU : TASK_TYPE);
        task.addCommand(author.Command("exec", {
            exe: PYTHON_EXE,
            args: ["-m", plan.module].concat(step.args),
        }));
        for (const dep of step.depends) {
            task.addDependency(authored.get(dep));
        }
        job.addTask(task);
        authored.set(step.id, task);
    }
    print(`neural-atlas: shot ${plan.shot}: ${plan.tasks.length} tasks`);
}

// parsePlan returns the validated plan, or throws one line naming what is wrong. The Manager answers a submission
// whose compilation throws with HTTP 400 and this message, so the submitter shows it as is.
function parsePlan(text, shot) {
    const bad = (what) => new Error(`neural-atlas job "${shot}": ${what} — ${RESUBMIT}`);
    if (typeof text !== "string" || text.length === 0) {
        throw bad("the plan setting is missing");
    }
    let plan;
    try {
        plan = JSON.parse(text);
    } catch (err) {
        throw bad(`the plan setting is not JSON (${err.message})`);
    }
    if (plan === null || typeof plan !== "object" || Array.isArray(plan)) {
        throw bad("the plan setting is not a JSON object");
    }
    if (plan[PLAN_TAG] !== PLAN_VERSION) {
        throw bad(`the plan is not a ${PLAN_TAG} version ${PLAN_VERSION} plan (got ${JSON.stringify(plan[PLAN_TAG])}); `
            + "the engine that submitted it and this job type differ: install this engine's job type on the Manager");
    }
    if (plan.shot !== shot) {
        throw bad(`the plan is for shot ${JSON.stringify(plan.shot)}`);
    }
    if (plan.module === undefined) {
        plan.module = "engine";
    }
    if (typeof plan.module !== "string" || !/^[A-Za-z_][A-Za-z0-9_]*$/.test(plan.module)) {
        throw bad(`the plan's module ${JSON.stringify(plan.module)} is not a Python module name`);
    }
    if (!Array.isArray(plan.tasks) || plan.tasks.length === 0) {
        throw bad("the plan has no tasks");
    }
    const seen = new Set();
    plan.tasks.forEach((step, index) => {
        const where = `task ${index + 1}`;
        if (step === null || typeof step !== "object" || Array.isArray(step)) {
            throw bad(`${where} is not an object`);
        }
        if (typeof step.id !== "string" || step.id.trim() === "") {
            throw bad(`${where} has no id`);
        }
        if (seen.has(step.id)) {
            throw bad(`${where}: the id ${JSON.stringify(step.id)} is used twice`);
        }
        if (TASK_KINDS.indexOf(step.kind) < 0) {
            throw bad(`task ${step.id}: unknown kind ${JSON.stringify(step.kind)} (one of ${TASK_KINDS.join(", ")})`);
        }
        if (!Array.isArray(step.args) || step.args.length === 0 || !step.args.every((a) => typeof a === "string")) {
            throw bad(`task ${step.id}: args must be a non-empty list of strings`);
        }
        if (!Array.isArray(step.depends) || !step.depends.every((d) => typeof d === "string")) {
            throw bad(`task ${step.id}: depends must be a list of task ids`);
        }
        for (const dep of step.depends) {
            if (!seen.has(dep)) {
                throw bad(`task ${step.id} depends on ${JSON.stringify(dep)}, which is not an earlier task of the plan`);
            }
        }
        if (typeof step.accelerator !== "boolean") {
            throw bad(`task ${step.id}: accelerator must be true or false`);
        }
        seen.add(step.id);
    });
    return plan;
}
