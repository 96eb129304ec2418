// A stand-in for Flamenco Manager's job compiler environment, so a custom job type can be tested
// under Node (Flamenco itself is not in Debian). It implements the documented surface the
// job-type scripts use -- the globals `author.Task(name, type)` (-> addCommand, addDependency),
// `author.Command(name, parameters)`, `print`, `frameChunker(frames, chunkSize)`, the `path`
// helpers (join, basename, dirname, stem) and `formatTimestampLocal` -- and the job object
// (`name`, `settings`, `created`, `addTask`). Settings are checked against the script's JOB_TYPE
// the way the Manager validates a submission: required keys present, defaults filled in, types
// `string`, `int32`, `float`, `bool`. The result is plain data (tasks with their commands and
// dependencies) that a test can inspect or execute like a Worker would.
"use strict";
const fs = require("fs");
const vm = require("vm");
const nodePath = require("path").posix;

const TYPES = {
    string: (v) => typeof v === "string",
    int32: (v) => Number.isInteger(v) && v >= -2147483648 && v <= 2147483647,
    float: (v) => typeof v === "number" && Number.isFinite(v),
    bool: (v) => typeof v === "boolean",
};
const SUBTYPES = new Set(["file_path", "dir_path", "file_name", "hashed_file_path"]);
const VISIBILITY = new Set(["visible", "submission", "web", "hidden"]);

// Flamenco's frameChunker: "1-10, 15" with chunkSize 3 -> ["1-3", "4-6", "7-9", "10", "15"].
function frameChunker(frames, chunkSize) {
    const all = new Set();
    for (const part of String(frames).split(",")) {
        const t = part.trim();
        if (!t) continue;
        const m = /^(-?\d+)(?:\s*-\s*(-?\d+))?$/.exec(t);
        if (!m) throw new Error(`frameChunker: bad frame range "${t}"`);
        const lo = parseInt(m[1], 10), hi = m[2] === undefined ? lo : parseInt(m[2], 10);
        if (hi < lo) throw new Error(`frameChunker: range "${t}" runs backwards`);
        for (let f = lo; f <= hi; f++) all.add(f);
    }
    const sorted = [...all].sort((a, b) => a - b);
    const chunks = [];
    let start = null, prev = null, count = 0;
    const flush = () => { if (start !== null) chunks.push(start === prev ? `${start}` : `${start}-${prev}`); };
    for (const f of sorted) {
        if (start !== null && f === prev + 1 && count < chunkSize) {
            prev = f;
            count++;
            continue;
        }
        flush();
        start = prev = f;
        count = 1;
    }
    flush();
    return chunks;
}

const pathHelpers = {
    join: (...parts) => nodePath.join(...parts),
    basename: (p) => nodePath.basename(p),
    dirname: (p) => nodePath.dirname(p),
    stem: (p) => nodePath.basename(p, nodePath.extname(p)),
};

function pad2(n) { return String(n).padStart(2, "0"); }
function formatTimestampLocal(d) {
    const t = d instanceof Date ? d : new Date(d);
    return `${t.getFullYear()}-${pad2(t.getMonth() + 1)}-${pad2(t.getDate())}_` +
        `${pad2(t.getHours())}${pad2(t.getMinutes())}${pad2(t.getSeconds())}`;
}

class AuthoredTask {
    constructor(name, type) {
        if (typeof name !== "string" || !name) throw new Error("author.Task: name must be a non-empty string");
        if (typeof type !== "string" || !type) throw new Error("author.Task: type must be a non-empty string");
        this.name = name;
        this.type = type;
        this.commands = [];
        this.dependencies = [];
    }
    addCommand(cmd) {
        if (!(cmd instanceof AuthoredCommand)) throw new Error("addCommand: not an author.Command");
        this.commands.push(cmd);
    }
    addDependency(task) {
        if (!(task instanceof AuthoredTask)) throw new Error("addDependency: not an author.Task");
        this.dependencies.push(task);
    }
}

class AuthoredCommand {
    constructor(name, parameters) {
        if (typeof name !== "string" || !name) throw new Error("author.Command: name must be a string");
        if (parameters === null || typeof parameters !== "object") {
            throw new Error("author.Command: parameters must be an object");
        }
        this.name = name;
        this.parameters = JSON.parse(JSON.stringify(parameters)); // what the Manager stores
    }
}

// Loads a job compiler script; returns {JOB_TYPE, compileJob, log}.
function loadJobType(file) {
    const log = [];
    const sandbox = {
        author: {
            Task: (name, type) => new AuthoredTask(name, type),
            Command: (name, params) => new AuthoredCommand(name, params),
        },
        print: (...a) => log.push(a.map(String).join(" ")),
        frameChunker,
        path: pathHelpers,
        formatTimestampLocal,
    };
    vm.createContext(sandbox);
    const src = fs.readFileSync(file, "utf8");
    vm.runInContext(src + "\n;globalThis.__jt = {JOB_TYPE, compileJob};", sandbox, { filename: file });
    const { JOB_TYPE, compileJob } = sandbox.__jt;
    checkJobType(JOB_TYPE);
    if (typeof compileJob !== "function") throw new Error(`${file}: no compileJob(job) function`);
    return { JOB_TYPE, compileJob, log };
}

function checkJobType(jt) {
    if (!jt || typeof jt.label !== "string" || !Array.isArray(jt.settings)) {
        throw new Error("JOB_TYPE needs a label and a settings array");
    }
    const seen = new Set();
    for (const s of jt.settings) {
        if (typeof s.key !== "string" || !/^[a-z_][a-z0-9_]*$/.test(s.key)) throw new Error(`bad setting key ${s.key}`);
        if (seen.has(s.key)) throw new Error(`duplicate setting ${s.key}`);
        seen.add(s.key);
        if (!TYPES[s.type]) throw new Error(`setting ${s.key}: unknown type ${s.type}`);
        if (s.subtype !== undefined && !SUBTYPES.has(s.subtype)) throw new Error(`setting ${s.key}: unknown subtype ${s.subtype}`);
        if (s.visible !== undefined && !VISIBILITY.has(s.visible)) throw new Error(`setting ${s.key}: bad visible ${s.visible}`);
        if (s.default !== undefined && !TYPES[s.type](s.default)) throw new Error(`setting ${s.key}: default is not a ${s.type}`);
        if (s.eval !== undefined && typeof s.eval !== "string") throw new Error(`setting ${s.key}: eval must be a Python expression string`);
        if (s.choices !== undefined && !Array.isArray(s.choices)) throw new Error(`setting ${s.key}: choices must be an array`);
    }
}

// Validates and completes submitted settings as the Manager does.
function resolveSettings(jt, submitted) {
    const out = {};
    for (const s of jt.settings) {
        let v = submitted[s.key];
        if (v === undefined && s.default !== undefined) v = s.default;
        if (v === undefined) {
            if (s.required) throw new Error(`setting ${s.key} is required`);
            continue;
        }
        if (!TYPES[s.type](v)) throw new Error(`setting ${s.key}: ${JSON.stringify(v)} is not a ${s.type}`);
        if (s.choices && !s.choices.includes(v)) throw new Error(`setting ${s.key}: not one of the choices`);
        out[s.key] = v;
    }
    for (const k of Object.keys(submitted)) {
        if (!jt.settings.some((s) => s.key === k)) throw new Error(`unknown setting ${k}`);
    }
    return out;
}

// Compiles a job; returns {tasks: [{name, type, commands, dependencies: [names]}], log}.
function compile(file, name, submitted, created = new Date()) {
    const { JOB_TYPE, compileJob, log } = loadJobType(file);
    const tasks = [];
    const job = {
        name,
        created,
        priority: 50,
        submitterPlatform: "linux",
        settings: resolveSettings(JOB_TYPE, submitted),
        metadata: {},
        addTask(t) {
            if (!(t instanceof AuthoredTask)) throw new Error("job.addTask: not an author.Task");
            if (tasks.some((x) => x.name === t.name)) throw new Error(`duplicate task name ${t.name}`);
            tasks.push(t);
        },
    };
    compileJob(job);
    const names = new Set(tasks.map((t) => t.name));
    for (const t of tasks) {
        for (const d of t.dependencies) {
            if (!names.has(d.name)) throw new Error(`task ${t.name} depends on ${d.name}, which was not added to the job`);
        }
    }
    return {
        settings: job.settings,
        tasks: tasks.map((t) => ({
            name: t.name, type: t.type,
            commands: t.commands.map((c) => ({ name: c.name, parameters: c.parameters })),
            dependencies: t.dependencies.map((d) => d.name),
        })),
        log,
    };
}

module.exports = { compile, loadJobType, frameChunker, resolveSettings };

// CLI: node flamenco_harness.js JOB_TYPE.js JOB_NAME SETTINGS.json  -> compiled job as JSON
if (require.main === module) {
    const [file, name, settingsFile] = process.argv.slice(2);
    if (!settingsFile) {
        console.error("usage: node flamenco_harness.js JOB_TYPE.js JOB_NAME SETTINGS.json");
        process.exit(2);
    }
    try {
        const settings = JSON.parse(fs.readFileSync(settingsFile, "utf8"));
        process.stdout.write(JSON.stringify(compile(file, name, settings), null, 1) + "\n");
    } catch (e) {
        console.error(`compile failed: ${e && e.message ? e.message : e}`);
        process.exit(1);
    }
}
