// SPDX-License-Identifier: GPL-3.0-or-later
//
// Tegument Bake: a Flamenco 3 job type that spreads a .blend's Tegument bakes over the farm.
//
// Install: copy this file into the `scripts` folder beside the `flamenco-manager` executable and
// restart the Manager (docs/farm.md). It ships inside the Tegument extension, in its `farm` folder.
//
// What the job compiles from: the hidden `scene_bakes` setting, which Blender's Flamenco add-on
// fills in at submission by evaluating `C.scene.tegument_farm_bakes` — the JSON that
// `blender -b shot.blend --command tegument list-bakes` prints. It lists each Pyramid Deform
// object and each Tegument UV Warp node with its frame range, its caches (relative to the .blend),
// the bakes it depends on and a command template with {first}, {last} and {preroll} in it. This
// script only selects, chunks and fills in those templates; the command format lives in the add-on.
//
// Tasks:
//   - one per Pyramid Deform object over its whole range: its frames carry history (collisions,
//     dynamics), so they are solved in order by one worker;
//   - one per chunk of `chunk_size` frames of each UV Warp node, each solving up to `preroll`
//     frames before its first one (not written) so that its warm start matches a bake that ran
//     through; chunks of one node run at once;
//   - a task that reads a deformer's cache (a warp on the deformed object, a deformer colliding
//     with another deformer) depends on that deformer's task when both are in the job.
// Each task is one `blender-render` command: `{blender} {blenderArgs} <blendfile> --command tegument …`.
// No task saves the .blend (several run on it at once); the caches are written atomically.

const JOB_TYPE = {
    label: "Tegument Bake",
    description: "Bake Tegument's Pyramid Deform caches and UV Warp sequences of a .blend",
    settings: [
        // Settings for artists to determine:
        {
            key: "bakes", type: "string", default: "everything",
            choices: ["everything", "pyramid_deform", "uv_warp", "listed"],
            description: "Which bakes: every Pyramid Deform object and UV Warp node, only one kind, "
                + "or the names in Bake List",
            visible: "submission",
        },
        {
            key: "bake_list", type: "string", default: "",
            description: "With Bakes = listed: comma-separated names, an object for Pyramid Deform, "
                + "Material/Node for a UV Warp node",
            visible: "submission",
        },
        {
            key: "frames", type: "string", default: "",
            description: "START-END for every bake; empty: each bake's own frame range",
            visible: "submission",
        },
        {
            key: "chunk_size", type: "int32", default: 12, propargs: { min: 1 },
            description: "Frames of a UV Warp node per task (a Pyramid Deform object is always one task)",
            visible: "submission",
        },
        {
            key: "preroll", type: "int32", default: 4, propargs: { min: 0 },
            description: "Frames a UV Warp chunk solves before its first one without writing them "
                + "(its warm start)",
            visible: "submission",
        },

        // Automatically evaluated settings:
        {
            key: "scene_bakes", type: "string", required: true,
            eval: "C.scene.tegument_farm_bakes",
            description: "Every Tegument bake of the .blend as JSON (what `tegument list-bakes` prints); "
                + "filled in by the Tegument add-on at submission",
            visible: "hidden",
        },
        {
            key: "blendfile", type: "string", required: true,
            description: "Path of the .blend to bake", visible: "web",
        },
    ],
};

const PYRAMID_DEFORM = "pyramid_deform";
const UV_WARP = "uv_warp";

function compileJob(job) {
    const settings = job.settings;
    const scene = parseSceneBakes(settings.scene_bakes);
    const span = parseFrames(settings.frames);
    const chunkSize = wholeNumber(settings.chunk_size, 12, 1, "chunk_size");
    const preroll = wholeNumber(settings.preroll, 4, 0, "preroll");
    const selected = selectBakes(scene.bakes, settings.bakes || "everything", settings.bake_list || "");

    const tasksOf = {}; // bake id -> its tasks
    for (const bake of orderByDependencies(selected)) {
        const problem = bake.problem;
        if (problem) {
            throw `Tegument bake: ${problem}`;
        }
        const tasks = [];
        for (const piece of bakePieces(bake, span, chunkSize, preroll)) {
            const task = author.Task(taskName(bake, piece.first, piece.last), "blender");
            task.addCommand(author.Command("blender-render", {
                exe: "{blender}",
                exeArgs: "{blenderArgs}",
                argsBefore: [],
                blendfile: settings.blendfile,
                args: fill(bake.args, piece.first, piece.last, piece.preroll),
            }));
            for (const id of bake.depends_on) {
                for (const before of tasksOf[id] || []) {
                    task.addDependency(before);
                }
            }
            job.addTask(task);
            tasks.push(task);
        }
        tasksOf[bake.id] = tasks;
    }
}

function taskName(bake, first, last) {
    const what = bake.kind === PYRAMID_DEFORM ? "Pyramid Deform" : "UV Warp";
    return `${what} ${bake.id} ${first}-${last}`;
}

// The job's frames (or the bake's own) as the tasks of one bake: the whole range for a Pyramid
// Deform object; chunks for a UV Warp node, each pre-rolling up to `preroll` frames but never
// before the first frame of the range (addon/farm/__init__.py, chunk_commands, does the same).
function bakePieces(bake, span, chunkSize, preroll) {
    const first = span ? span[0] : bake.frames[0];
    const last = span ? span[1] : bake.frames[1];
    if (bake.kind === PYRAMID_DEFORM && span && span[0] !== bake.frames[0]) {
        // The cache starts at its first frame baked, and the object's Mesh Cache modifier at
        // the Start saved in the .blend, which no task changes.
        throw `Tegument bake: the cache of ${bake.id} starts at frame ${bake.frames[0]} in the .blend, `
            + `but Frames asks for ${first}-${last}: set ${bake.id}'s Start to ${first} in Blender `
            + `and submit again, or leave Frames empty`;
    }
    if (!bake.chunked) {
        return [{ first: first, last: last, preroll: 0 }];
    }
    const pieces = [];
    for (let start = first; start <= last; start += chunkSize) {
        pieces.push({
            first: start,
            last: Math.min(start + chunkSize - 1, last),
            preroll: Math.min(preroll, start - first),
        });
    }
    return pieces;
}

function fill(args, first, last, preroll) {
    return args.map((arg) => arg
        .split("{first}").join(String(first))
        .split("{last}").join(String(last))
        .split("{preroll}").join(String(preroll)));
}

function parseSceneBakes(text) {
    if (!text) {
        throw "Tegument bake: the scene_bakes setting is empty: submit from Blender with the Tegument "
            + "add-on enabled, or paste what `blender -b FILE --command tegument list-bakes` prints";
    }
    let scene;
    try {
        scene = JSON.parse(text);
    } catch (error) {
        throw `Tegument bake: scene_bakes is not the JSON of tegument list-bakes: ${error}`;
    }
    if (scene.error) {
        throw `Tegument bake: ${scene.error}`;
    }
    if (!scene.bakes || !scene.bakes.length) {
        throw "Tegument bake: the .blend has no Pyramid Deform object and no Tegument UV Warp node";
    }
    return scene;
}

function parseFrames(text) {
    const trimmed = (text || "").trim();
    if (!trimmed) {
        return null;
    }
    const match = /^(\d+)\s*-\s*(\d+)$/.exec(trimmed);
    if (!match) {
        throw `Tegument bake: Frames expects START-END (like 1001-1100) or nothing, got "${text}"`;
    }
    const first = parseInt(match[1], 10);
    const last = parseInt(match[2], 10);
    if (last < first) {
        throw `Tegument bake: Frames ${trimmed}: the last frame ${last} comes before the first ${first}`;
    }
    return [first, last];
}

function wholeNumber(value, fallback, minimum, key) {
    if (value === undefined || value === null || value === "") {
        return fallback;
    }
    const number = Number(value);
    if (!Number.isInteger(number) || number < minimum) {
        throw `Tegument bake: ${key} must be a whole number of at least ${minimum}, got ${value}`;
    }
    return number;
}

function selectBakes(bakes, which, list) {
    if (which === "everything") {
        return bakes;
    }
    if (which === PYRAMID_DEFORM || which === UV_WARP) {
        const kind = bakes.filter((bake) => bake.kind === which);
        if (!kind.length) {
            const what = which === PYRAMID_DEFORM ? "Pyramid Deform object" : "Tegument UV Warp node";
            throw `Tegument bake: Bakes is ${which}, but the .blend has no ${what}`;
        }
        return kind;
    }
    if (which !== "listed") {
        throw `Tegument bake: Bakes must be everything, pyramid_deform, uv_warp or listed, got "${which}"`;
    }
    const names = list.split(",").map((name) => name.trim()).filter((name) => name);
    if (!names.length) {
        throw "Tegument bake: Bakes is listed, but Bake List is empty";
    }
    const byId = {};
    for (const bake of bakes) {
        byId[bake.id] = bake;
    }
    const unknown = names.filter((name) => !(name in byId));
    if (unknown.length) {
        throw `Tegument bake: no bake named ${unknown.map((n) => `"${n}"`).join(", ")} in the .blend; `
            + `it has ${bakes.map((b) => `"${b.id}"`).join(", ")} (objects for Pyramid Deform, `
            + "Material/Node for UV Warp)";
    }
    return bakes.filter((bake) => names.indexOf(bake.id) >= 0);
}

// Bakes in an order where each comes after the bakes it depends on (list-bakes refuses cycles),
// otherwise in the order of the scene.
function orderByDependencies(bakes) {
    const byId = {};
    for (const bake of bakes) {
        byId[bake.id] = bake;
    }
    const ordered = [];
    const placed = {};
    const visit = (bake, path) => {
        if (placed[bake.id]) {
            return;
        }
        if (path.indexOf(bake.id) >= 0) {
            throw `Tegument bake: ${path.concat([bake.id]).join(" → ")} depend on each other`;
        }
        for (const id of bake.depends_on) {
            if (byId[id]) {
                visit(byId[id], path.concat([bake.id]));
            }
        }
        placed[bake.id] = true;
        ordered.push(bake);
    };
    for (const bake of bakes) {
        visit(bake, []);
    }
    return ordered;
}
