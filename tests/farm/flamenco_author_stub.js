// A stand-in for Flamenco Manager's job compiler, for the contract test of engine/farm/flamenco/neural-atlas.js.
//
// Flamenco cannot be installed here, so this runs a job compiler script the way the Manager does (Flamenco 3.x,
// internal/manager/job_compilers): the script is evaluated in a fresh global scope that has `author` (Task,
// Command), `print` and `alert`; its `JOB_TYPE` is read and `compileJob(job)` is called with a job whose
// `settings` are the submitted job's settings and which has `addTask`. Authored tasks have `addCommand` and
// `addDependency`, as the Manager's AuthoredTask. Checks the Manager makes are made here too: JOB_TYPE's settings
// (key, type, visible), required settings, non-empty task names and types, task names unique in the job.
//
// usage: node flamenco_author_stub.js SCRIPT.js JOB.json
//   JOB.json: a SubmittedJob ({name, type, priority, settings, metadata, submitter_platform, ...})
// stdout: {"job_type": JOB_TYPE, "tasks": [{"name", "type", "commands": [{"name", "parameters"}],
//          "dependencies": [task names]}]}
// a script that throws: its message on stderr, exit 3; a broken contract: the reason on stderr, exit 4.

"use strict";

const fs = require("fs");
const vm = require("vm");

const SETTING_TYPES = ["string", "int32", "float", "bool"];
const SETTING_VISIBILITY = ["visible", "hidden", "submission", "web"];

function contractError(message) {
    process.stderr.write(`contract: ${message}\n`);
    process.exit(4);
}

function makeAuthor() {
    return {
        Task(name, type) {
            name = String(name === undefined ? "" : name).trim();
            type = String(type === undefined ? "" : type).trim();
            if (name === "") throw new Error("author.Task(name, type): name is required");
            if (type === "") throw new Error("author.Task(name, type): type is required");
            const task = {
                name, type, priority: 50, commands: [], dependencies: [],
                addCommand(cmd) {
                    if (!cmd || typeof cmd.name !== "string") contractError(`task ${name}: addCommand needs an author.Command`);
                    task.commands.push(cmd);
                },
                addDependency(dep) {
                    if (!dep || !Array.isArray(dep.commands)) contractError(`task ${name}: addDependency needs an author.Task`);
                    task.dependencies.push(dep);
                },
            };
            return task;
        },
        Command(name, parameters, totalStepCount) {
            return { name, parameters, totalStepCount: totalStepCount || 0 };
        },
    };
}

function checkJobType(jobType) {
    if (!jobType || typeof jobType !== "object") contractError("the script defines no JOB_TYPE object");
    if (typeof jobType.label !== "string" || jobType.label === "") contractError("JOB_TYPE has no label");
    if (!Array.isArray(jobType.settings)) contractError("JOB_TYPE has no settings list");
    const keys = new Set();
    for (const setting of jobType.settings) {
        if (typeof setting.key !== "string" || setting.key === "") contractError("a JOB_TYPE setting has no key");
        if (keys.has(setting.key)) contractError(`JOB_TYPE setting ${setting.key} is defined twice`);
        keys.add(setting.key);
        if (SETTING_TYPES.indexOf(setting.type) < 0) contractError(`JOB_TYPE setting ${setting.key}: type ${setting.type}`);
        if (setting.visible !== undefined && SETTING_VISIBILITY.indexOf(setting.visible) < 0) {
            contractError(`JOB_TYPE setting ${setting.key}: visible ${setting.visible}`);
        }
    }
}

function main() {
    const [scriptPath, jobPath] = process.argv.slice(2);
    const submitted = JSON.parse(fs.readFileSync(jobPath, "utf8"));
    const context = vm.createContext({
        author: makeAuthor(),
        print: (...args) => process.stderr.write(`print: ${args.join(" ")}\n`),
        alert: (...args) => process.stderr.write(`alert: ${args.join(" ")}\n`),
    });
    vm.runInContext(fs.readFileSync(scriptPath, "utf8"), context, { filename: scriptPath });
    // top-level const/let live in the context's global lexical scope, visible to later scripts in it
    const jobType = vm.runInContext("typeof JOB_TYPE === 'undefined' ? undefined : JOB_TYPE", context);
    checkJobType(jobType);
    if (vm.runInContext("typeof compileJob", context) !== "function") contractError("the script defines no compileJob(job)");

    const settings = Object.assign({}, submitted.settings || {});
    for (const setting of jobType.settings) {
        if (setting.required && (settings[setting.key] === undefined || settings[setting.key] === "")) {
            process.stderr.write(`required setting ${setting.key} is missing\n`);
            process.exit(3);
        }
    }
    const job = {
        name: submitted.name, type: submitted.type, priority: submitted.priority,
        settings, metadata: Object.assign({}, submitted.metadata || {}), tasks: [],
        addTask(task) {
            if (!task || !Array.isArray(task.commands)) contractError("job.addTask needs an author.Task");
            job.tasks.push(task);
        },
    };
    try {
        context.__job = job;
        vm.runInContext("compileJob(__job)", context);
    } catch (err) {
        process.stderr.write(`${err && err.message !== undefined ? err.message : err}\n`);
        process.exit(3);
    }
    const names = new Set();
    for (const task of job.tasks) {
        if (names.has(task.name)) contractError(`task name ${task.name} is used twice`);
        names.add(task.name);
        for (const dep of task.dependencies) {
            if (job.tasks.indexOf(dep) < 0) contractError(`task ${task.name} depends on a task not added to the job`);
        }
    }
    const out = {
        job_type: jobType,
        tasks: job.tasks.map((t) => ({
            name: t.name,
            type: t.type,
            commands: t.commands.map((c) => ({ name: c.name, parameters: c.parameters })),
            dependencies: t.dependencies.map((d) => d.name),
        })),
    };
    process.stdout.write(JSON.stringify(out));
}

main();
