// SPDX-License-Identifier: GPL-3.0-or-later
//
// A stand-in for the part of Flamenco 3's Manager that compiles a job, for testing a job type
// without Flamenco (which the project's package registries do not offer).
//
//   node flamenco_host.js JOB_TYPE.js JOB.json  ->  stdout: {"job_type": …, "tasks": […]}
//
// JOB.json is {"name": …, "settings": {…}}, what Blender's Flamenco add-on submits. On a
// compile error (the script throws, as Flamenco's own scripts do) the message goes to stderr
// and the exit code is 1.
//
// What it stands in for, after Flamenco's documentation ("Job Types") and the Manager's
// `AvailableJobSetting` schema:
//   - the script runs as a plain script in a fresh global scope that holds `author`, `print`
//     and nothing from Node (no `require`, no `process`);
//   - `JOB_TYPE` must be a top-level object with a `label` and `settings`, each setting with a
//     unique `key`, a `type` of string/int32/float/bool, `choices` only on strings, `visible`
//     one of visible/hidden/submission/web; required settings must be in the submitted job,
//     and settings the job leaves out get their `default` (as the Manager fills them in);
//   - `compileJob(job)` is called with `job.settings` and `job.addTask(task)`;
//   - `author.Task(name, type)` gives a task with `addCommand(command)` and
//     `addDependency(task)`; `author.Command(name, parameters)` gives a command.
// It checks what the Manager refuses: a dependency on a task that is not in the job. It also
// refuses two tasks of one name, which Flamenco allows but which would make its task list
// ambiguous to read. It does not stand in for Flamenco's `path`, `frameChunker` or
// `formatTimestampLocal` helpers: the Tegument job type does not use them, and using one makes
// this host fail loudly (ReferenceError).

"use strict";

const fs = require("fs");
const vm = require("vm");

const SETTING_TYPES = { string: "string", int32: "number", float: "number", bool: "boolean" };
const VISIBILITY = ["visible", "hidden", "submission", "web"];

function fail(message) {
    process.stderr.write(`${message}\n`);
    process.exit(1);
}

function checkJobType(jobType) {
    if (typeof jobType !== "object" || jobType === null) {
        fail("JOB_TYPE is not an object");
    }
    if (typeof jobType.label !== "string" || !jobType.label) {
        fail("JOB_TYPE has no label");
    }
    if (!Array.isArray(jobType.settings)) {
        fail("JOB_TYPE.settings is not a list");
    }
    const keys = new Set();
    for (const setting of jobType.settings) {
        if (typeof setting.key !== "string" || !setting.key) {
            fail(`a setting has no key: ${JSON.stringify(setting)}`);
        }
        if (keys.has(setting.key)) {
            fail(`two settings have the key ${setting.key}`);
        }
        keys.add(setting.key);
        if (!(setting.type in SETTING_TYPES)) {
            fail(`setting ${setting.key} has type ${setting.type}, not one of ${Object.keys(SETTING_TYPES)}`);
        }
        if ("default" in setting && typeof setting.default !== SETTING_TYPES[setting.type]) {
            fail(`setting ${setting.key}: default ${JSON.stringify(setting.default)} is not a ${setting.type}`);
        }
        if ("choices" in setting) {
            if (setting.type !== "string") {
                fail(`setting ${setting.key}: choices on a ${setting.type} setting`);
            }
            if ("default" in setting && setting.choices.indexOf(setting.default) < 0) {
                fail(`setting ${setting.key}: default ${setting.default} is not one of its choices`);
            }
        }
        if ("visible" in setting && VISIBILITY.indexOf(setting.visible) < 0) {
            fail(`setting ${setting.key}: visible is ${JSON.stringify(setting.visible)}, not one of ${VISIBILITY}`);
        }
    }
}

function main() {
    const [scriptPath, jobPath] = process.argv.slice(2);
    if (!scriptPath || !jobPath) {
        fail("usage: node flamenco_host.js JOB_TYPE.js JOB.json");
    }
    const submitted = JSON.parse(fs.readFileSync(jobPath, "utf8"));
    const printed = [];
    const context = vm.createContext({
        print: (...parts) => printed.push(parts.map(String).join(" ")),
        author: {
            Task(name, type) {
                if (typeof name !== "string" || typeof type !== "string") {
                    throw new Error(`author.Task(name, type) takes two strings, got ${name}, ${type}`);
                }
                return {
                    name: name,
                    type: type,
                    commands: [],
                    dependencies: [],
                    addCommand(command) {
                        this.commands.push(command);
                    },
                    addDependency(task) {
                        this.dependencies.push(task);
                    },
                };
            },
            Command(name, parameters) {
                return { name: name, parameters: parameters };
            },
        },
    });
    vm.runInContext(fs.readFileSync(scriptPath, "utf8"), context, { filename: scriptPath });
    // Top-level const/let live in the script scope the context shares, not on its global object.
    const jobType = vm.runInContext("typeof JOB_TYPE === 'undefined' ? undefined : JOB_TYPE", context);
    const compile = vm.runInContext("typeof compileJob === 'undefined' ? undefined : compileJob", context);
    if (jobType === undefined) {
        fail(`${scriptPath} defines no JOB_TYPE`);
    }
    if (typeof compile !== "function") {
        fail(`${scriptPath} defines no compileJob(job) function`);
    }
    checkJobType(jobType);

    const settings = Object.assign({}, submitted.settings);
    for (const setting of jobType.settings) {
        if (!(setting.key in settings)) {
            if (setting.required) {
                fail(`the job lacks the required setting ${setting.key}`);
            }
            if ("default" in setting) {
                settings[setting.key] = setting.default;
            }
        }
    }
    const tasks = [];
    const job = {
        name: submitted.name || "job",
        settings: settings,
        addTask(task) {
            tasks.push(task);
        },
    };
    try {
        compile(job);
    } catch (error) {
        fail(String(error && error.message !== undefined ? error.message : error));
    }

    const names = new Set();
    for (const task of tasks) {
        if (names.has(task.name)) {
            fail(`two tasks are named ${task.name}`);
        }
        names.add(task.name);
    }
    for (const task of tasks) {
        for (const dependency of task.dependencies) {
            if (tasks.indexOf(dependency) < 0) {
                fail(`task ${task.name} depends on ${dependency.name}, which is not in the job`);
            }
        }
    }
    process.stdout.write(JSON.stringify({
        job_type: jobType,
        printed: printed,
        tasks: tasks.map((task) => ({
            name: task.name,
            type: task.type,
            commands: task.commands,
            dependencies: task.dependencies.map((d) => d.name),
        })),
    }));
}

main();
