// deploy/flamenco/proden_passes.js compiled by the Flamenco harness: the harness itself behaves as
// documented (frameChunker), and the job type yields one registration task plus frames x passes
// pass tasks, pass-major, with distinct seeds per frame, outputs in proden's watched layout, the
// proden job spec the API accepts, and clear errors for bad settings.
"use strict";
const assert = require("assert");
const path = require("path");
const { compile, frameChunker } = require("./flamenco_harness");

const JOB = path.join(__dirname, "..", "..", "deploy", "flamenco", "proden_passes.js");
const BASE = {
    frames: "1-3, 7",
    passes: 4,
    spp: 32,
    render_output_root: "/srv/renders",
    proden_url: "http://proden.farm:8080",
    proden_tools: "/srv/proden",
    blendfile: "/srv/shots/shot010.blend",
    scene: "Scene",
    render_engine: "CYCLES",
};
let checks = 0;
function check(name, fn) {
    fn();
    checks++;
    console.log("ok", name);
}

check("frameChunker follows Flamenco's chunking", () => {
    assert.deepStrictEqual(frameChunker("1-10, 15", 3), ["1-3", "4-6", "7-9", "10", "15"]);
    assert.deepStrictEqual(frameChunker("3,1,2", 1), ["1", "2", "3"]);
    assert.deepStrictEqual(frameChunker("5", 4), ["5"]);
    assert.throws(() => frameChunker("1-x", 1));
});

function argOf(args, flag) {
    const i = args.indexOf(flag);
    assert.ok(i >= 0, `${flag} missing in ${args}`);
    return args[i + 1];
}

check("wrapper mode: registration + frames x passes, pass-major, distinct seeds", () => {
    const job = compile(JOB, "shot 010!", Object.assign({}, BASE, { target_equivalent_spp: 1024, min_passes: 3 }));
    const tasks = job.tasks;
    assert.strictEqual(tasks.length, 1 + 4 * 4);
    const reg = tasks[0];
    assert.strictEqual(reg.name, "proden-register");
    assert.strictEqual(reg.commands[0].name, "exec");
    const regArgs = reg.commands[0].parameters.args;
    assert.strictEqual(regArgs[0], "/srv/proden/clients/python/proden_client.py");
    assert.strictEqual(argOf(regArgs, "--url"), "http://proden.farm:8080");
    const spec = JSON.parse(regArgs[regArgs.length - 1]);
    assert.strictEqual(spec.name, "shot_010_");          // proden job names: [A-Za-z0-9._-]
    assert.deepStrictEqual(spec.watch, { dir: "/srv/renders/shot_010_", pattern: "pass_{pass}/beauty_####.exr" });
    assert.deepStrictEqual(spec.target, { equivalent_spp: 1024 });
    assert.strictEqual(spec.min_passes, 3);
    assert.strictEqual(spec.output.dir, "/srv/renders/shot_010_/proden");

    const seen = new Map();  // frame -> seeds
    tasks.slice(1).forEach((t, i) => {
        assert.deepStrictEqual(t.dependencies, ["proden-register"]);
        assert.strictEqual(t.type, "blender");
        const a = t.commands[0].parameters.args;
        assert.strictEqual(t.commands[0].name, "exec");
        assert.strictEqual(argOf(a, "--index"), String(i));
        assert.strictEqual(argOf(a, "--frames"), "1,2,3,7");
        assert.strictEqual(argOf(a, "--passes"), "4");
        assert.strictEqual(argOf(a, "--blender"), "{blender}");
        assert.strictEqual(argOf(a, "--job-name"), "shot_010_");
        const frame = [1, 2, 3, 7][i % 4], p = Math.floor(i / 4);
        assert.strictEqual(t.name, `pass-${String(p).padStart(4, "0")}-frame-${String(frame).padStart(4, "0")}`);
        if (!seen.has(frame)) seen.set(frame, new Set());
        seen.get(frame).add(Number(argOf(a, "--seed-base")) + p);
    });
    for (const [, seeds] of seen) assert.strictEqual(seeds.size, 4);
    // Pass-major: every frame's pass 0 comes before any pass 1.
    assert.deepStrictEqual(tasks.slice(1, 5).map((t) => t.name.slice(0, 9)), Array(4).fill("pass-0000"));
});

check("blender-render mode writes the watched layout with proden_pass.py", () => {
    const job = compile(JOB, "shot010", Object.assign({}, BASE, { skip_converged: false, seed_base: 100, view_layer: "FG" }));
    const pattern = /^\/srv\/renders\/shot010\/pass_(\d{4})\/beauty_(\d{4,})\.exr$/;
    const seeds = new Map();
    for (const t of job.tasks.slice(1)) {
        const c = t.commands[0];
        assert.strictEqual(c.name, "blender-render");
        assert.strictEqual(c.parameters.exe, "{blender}");
        assert.strictEqual(c.parameters.exeArgs, "{blenderArgs}");
        assert.strictEqual(c.parameters.blendfile, "/srv/shots/shot010.blend");
        const a = c.parameters.args;
        assert.deepStrictEqual(a.slice(0, 3), ["--python", "/srv/proden/deploy/blender/proden_pass.py", "--"]);
        const m = pattern.exec(argOf(a, "--out"));
        assert.ok(m, argOf(a, "--out"));
        assert.strictEqual(Number(m[2]), Number(argOf(a, "--frame")));
        assert.strictEqual(argOf(a, "--seed"), String(100 + Number(m[1])));
        assert.strictEqual(argOf(a, "--view-layer"), "FG");
        const key = `${m[2]}/${argOf(a, "--seed")}`;
        assert.ok(!seeds.has(key), `seed reused for a frame: ${key}`);
        seeds.set(key, true);
    }
    assert.strictEqual(seeds.size, 16);
    const spec = JSON.parse(job.tasks[0].commands[0].parameters.args.slice(-1)[0]);
    assert.strictEqual(spec.view_layer, "FG");
    assert.strictEqual(spec.target, undefined);  // no target: proden only publishes versions
});

check("bad settings are refused with a message naming them", () => {
    const bad = (over, re) => assert.throws(() => compile(JOB, "s", Object.assign({}, BASE, over)), re);
    bad({ passes: 0 }, /passes must be a positive integer/);
    bad({ passes: 2.5 }, /passes: 2.5 is not a int32/);
    bad({ target_relmse: 1e-3, target_equivalent_spp: 64 }, /not both/);
    bad({ render_engine: "BLENDER_EEVEE" }, /need Cycles/);
    bad({ proden_url: "proden:8080" }, /not a URL/);
    bad({ frames: "" }, /no frames/);
    assert.throws(() => compile(JOB, "s", Object.assign({}, BASE, { proden_tools: undefined })), /proden_tools is required/);
    assert.throws(() => compile(JOB, "s", Object.assign({}, BASE, { unknown_key: 1 })), /unknown setting/);
});

console.log(`${checks} checks passed`);
