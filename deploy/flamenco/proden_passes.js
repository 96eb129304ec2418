// SPDX-License-Identifier: GPL-3.0-or-later
// proden progressive passes: a Flamenco 3 custom job type (a job compiler script: JOB_TYPE and
// compileJob(job), Flamenco's documented `author` API). It renders every frame of a .blend as
// independent Cycles *passes* (distinct seeds, adaptive sampling and denoising off) into proden's
// watched layout <watch>/pass_<p>/beauty_<frame>.exr, and first registers the proden job over
// REST, so proden publishes a better frame after every pass and can say when a frame is good
// enough. Install: copy this file (only this file) into the `scripts/` directory next to
// flamenco-manager. NOT YET RUN ON A REAL FLAMENCO MANAGER: it is tested under Node with a
// harness implementing the documented API (deploy/flamenco/README.md).

const JOB_TYPE = {
    label: "proden Progressive Passes",
    description: "Render frames as independent Cycles passes that proden accumulates and denoises; " +
        "passes of converged frames are skipped",
    settings: [
        // Chosen by the artist.
        { key: "frames", type: "string", required: true,
          eval: "f'{C.scene.frame_start}-{C.scene.frame_end}'",
          evalInfo: { showLinkButton: true, description: "Scene frame range" },
          description: "Frame range to render. Examples: '47', '1-30', '3, 5-10, 47-327'" },
        { key: "passes", type: "int32", default: 16, propargs: { min: 1, max: 9999 },
          description: "Passes per frame: the sample budget is passes x samples per pass" },
        { key: "spp", type: "int32", default: 64, propargs: { min: 1, max: 65536 },
          description: "Cycles samples per pass" },
        { key: "seed_base", type: "int32", default: 1, visible: "submission",
          description: "Pass p of every frame renders with Cycles seed seed_base + p" },
        { key: "render_output_root", type: "string", subtype: "dir_path", required: true,
          visible: "submission",
          description: "Base directory; passes go to <root>/<job name>/pass_<p>/beauty_<frame>.exr" },
        { key: "view_layer", type: "string", required: false, visible: "submission",
          description: "Render only this view layer (empty: all; proden takes the first " +
              "alphabetically unless its job says otherwise)" },

        // proden.
        { key: "proden_url", type: "string", required: true, default: "http://127.0.0.1:8080",
          visible: "submission", description: "URL of proden serve, as seen from the workers" },
        { key: "proden_token_file", type: "string", subtype: "file_path", required: false,
          visible: "submission", description: "Bearer token file of proden serve, on the workers" },
        { key: "proden_tools", type: "string", subtype: "dir_path", required: true,
          visible: "submission",
          description: "proden checkout (or copy of its deploy/ and clients/) on shared storage" },
        { key: "proden_output_dir", type: "string", subtype: "dir_path", required: false,
          visible: "submission", description: "Where proden publishes (default <watch>/proden)" },
        { key: "target_relmse", type: "float", default: 0.0, visible: "submission",
          description: "Stop rendering a frame once proden's relMSE estimate is below this " +
              "with confidence (0: no target)" },
        { key: "target_equivalent_spp", type: "float", default: 0.0, visible: "submission",
          description: "...or once proden's frame is worth this many plain samples (0: none)" },
        { key: "min_passes", type: "int32", default: 2, propargs: { min: 1, max: 9999 },
          visible: "submission", description: "Passes before a frame may converge" },
        { key: "skip_converged", type: "bool", default: true, visible: "submission",
          description: "Each pass task asks proden first and skips the render if its frame has " +
              "converged (runs through proden's task wrapper with the exec command)" },
        { key: "python", type: "string", default: "python3", visible: "submission",
          description: "Python 3 on the workers (for the registration and the task wrapper)" },

        // Evaluated from the .blend by the add-on.
        { key: "blendfile", type: "string", required: true, visible: "web",
          description: "Path of the Blend file to render" },
        { key: "scene", type: "string", required: true, eval: "C.scene.name", visible: "web",
          description: "Name of the scene to render" },
        { key: "render_engine", type: "string", required: true, eval: "C.scene.render.engine",
          visible: "hidden" },
    ],
};

// proden's watch pattern for these passes (docs/api.md): {pass} = 4-digit pass number.
const PRODEN_PATTERN = "pass_{pass}/beauty_####.exr";

function compileJob(job) {
    const settings = job.settings;
    checkSettings(settings);
    const watchDir = path.join(settings.render_output_root, safeName(job.name));
    const outDir = settings.proden_output_dir || path.join(watchDir, "proden");
    const frames = expandFrames(settings.frames);
    const passes = settings.passes;

    const register = authorRegisterTask(job, settings, watchDir, outDir);
    job.addTask(register);
    // Pass-major order: every frame gets its first passes before any frame gets many.
    for (let p = 0; p < passes; p++) {
        for (let i = 0; i < frames.length; i++) {
            const index = p * frames.length + i;
            const task = authorPassTask(job, settings, watchDir, frames, index);
            task.addDependency(register);
            job.addTask(task);
        }
    }
    print(`proden: ${frames.length} frame(s) x ${passes} pass(es) of ${settings.spp} spp into ${watchDir}`);
}

function checkSettings(s) {
    if (s.render_engine && s.render_engine !== "CYCLES") {
        throw `proden passes need Cycles; the scene renders with ${s.render_engine}`;
    }
    for (const key of ["passes", "spp", "min_passes"]) {
        if (!Number.isInteger(s[key]) || s[key] < 1) throw `${key} must be a positive integer`;
    }
    if (!Number.isInteger(s.seed_base) || s.seed_base < 0) throw "seed_base must be >= 0";
    if (s.target_relmse > 0 && s.target_equivalent_spp > 0) {
        throw "set target_relmse or target_equivalent_spp, not both";
    }
    if (!/^https?:\/\/[^\s/]+/.test(s.proden_url)) throw `proden_url is not a URL: ${s.proden_url}`;
}

// proden job names: 1-64 of A-Z a-z 0-9 . _ -
function safeName(name) {
    const n = String(name).replace(/[^A-Za-z0-9._-]+/g, "_").replace(/^[._]+/, "").slice(0, 64);
    if (!n) throw `job name ${name} has no usable character for a proden job name`;
    return n;
}

// Flamenco's frameChunker with chunks of one frame gives every frame as its own string.
function expandFrames(spec) {
    const out = [];
    for (const chunk of frameChunker(spec, 1)) {
        const f = parseInt(chunk, 10);
        if (!(f >= 0) || String(f) !== String(chunk).trim()) throw `bad frame ${chunk} in ${spec}`;
        out.push(f);
    }
    if (out.length === 0) throw `no frames in ${spec}`;
    return out;
}

function pad(n, width) {
    let s = String(n);
    while (s.length < width) s = "0" + s;
    return s;
}

function prodenJobSpec(job, settings, watchDir, outDir) {
    const spec = {
        name: safeName(job.name),
        renderer: "cycles",
        watch: { dir: watchDir, pattern: PRODEN_PATTERN },
        output: { dir: outDir, formats: ["exr", "png"] },
        min_passes: settings.min_passes,
    };
    if (settings.target_relmse > 0) spec.target = { relmse: settings.target_relmse };
    if (settings.target_equivalent_spp > 0) {
        spec.target = { equivalent_spp: settings.target_equivalent_spp };
    }
    if (settings.view_layer) spec.view_layer = settings.view_layer;
    return spec;
}

function clientArgs(settings) {
    const args = [path.join(settings.proden_tools, "clients", "python", "proden_client.py"),
                  "--url", settings.proden_url];
    if (settings.proden_token_file) args.push("--token-file", settings.proden_token_file);
    return args;
}

function authorRegisterTask(job, settings, watchDir, outDir) {
    const task = author.Task("proden-register", "misc");
    const spec = prodenJobSpec(job, settings, watchDir, outDir);
    task.addCommand(author.Command("exec", {
        exe: settings.python,
        args: clientArgs(settings).concat(["ensure-job", JSON.stringify(spec)]),
    }));
    return task;
}

function passArgs(settings, frame, p, out) {
    const args = ["--seed", String(settings.seed_base + p), "--spp", String(settings.spp),
                  "--frame", String(frame), "--out", out];
    if (settings.scene) args.push("--scene", settings.scene);
    if (settings.view_layer) args.push("--view-layer", settings.view_layer);
    return args;
}

// POSIX shell quoting (the wrapper splits --blender-args with Python's shlex).
function shellQuote(s) {
    return "'" + String(s).replace(/'/g, "'\\''") + "'";
}

function authorPassTask(job, settings, watchDir, frames, index) {
    const frame = frames[index % frames.length];
    const p = Math.floor(index / frames.length);
    const task = author.Task(`pass-${pad(p, 4)}-frame-${pad(frame, 4)}`, "blender");
    const out = path.join(watchDir, `pass_${pad(p, 4)}`, `beauty_${pad(frame, 4)}.exr`);
    const passScript = path.join(settings.proden_tools, "deploy", "blender", "proden_pass.py");
    if (settings.skip_converged) {
        // The Slurm task wrapper works on any farm: it asks proden whether the frame converged,
        // renders pass `index` of the same pass-major layout otherwise, and writes atomically.
        const blenderArgs = [];
        if (settings.scene) blenderArgs.push("--scene", shellQuote(settings.scene));
        if (settings.view_layer) blenderArgs.push("--view-layer", shellQuote(settings.view_layer));
        task.addCommand(author.Command("exec", {
            exe: settings.python,
            args: [path.join(settings.proden_tools, "deploy", "slurm", "proden_slurm.py"), "task",
                   "--url", settings.proden_url]
                .concat(settings.proden_token_file ? ["--token-file", settings.proden_token_file] : [])
                .concat(["--job-name", safeName(job.name), "--watch", watchDir,
                         "--frames", frames.join(","), "--passes", String(settings.passes),
                         "--spp", String(settings.spp), "--seed-base", String(settings.seed_base),
                         "--index", String(index), "--blend", settings.blendfile,
                         "--blender", "{blender}"])
                .concat(blenderArgs.length ? ["--blender-args", blenderArgs.join(" ")] : []),
        }));
    } else {
        task.addCommand(author.Command("blender-render", {
            exe: "{blender}",
            exeArgs: "{blenderArgs}",
            argsBefore: [],
            blendfile: settings.blendfile,
            args: ["--python", passScript, "--"].concat(passArgs(settings, frame, p, out)),
        }));
    }
    return task;
}
