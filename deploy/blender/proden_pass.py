"""Render one proden *pass* of one frame of a .blend file with Cycles (Blender 3.x/4.x, bpy).

    blender -b shot.blend -P deploy/blender/proden_pass.py -- \
        --seed 7 --spp 64 --frame 12 --out /srv/renders/shot010/pass_07/beauty_####.exr

A pass is an independent batch of samples of a frame: passes of one frame must differ only in
their random numbers (README "Statistics"), so this script changes only what makes a render a
valid pass and leaves the look of the shot alone:

* `scene.cycles.seed` = --seed (distinct per pass; never reuse one for the same frame) and
  `use_animated_seed` off, `samples` = --spp, sample offset 0;
* adaptive sampling, time limit and Cycles denoising off (adaptive sampling varies the sample count
  per pixel and a denoised pass is not a sample mean; proden denoises);
* output OpenEXR multilayer, 32-bit float, ZIP (proden reads the Cycles layer names and the
  `cycles.<ViewLayer>.samples` header), with the Denoising Data passes (albedo, normal, depth:
  proden's features) unless --no-denoising-data; --keep-format keeps the .blend's own EXR format
  (single-layer OPEN_EXR also works: proden recognises it by its cycles.*.samples header);
* no placeholder files, written to a temporary name and renamed when complete, so a watcher never
  reads half a file.

`####` in --out is replaced by the frame number padded to as many digits as there are #s
(Blender's convention). --view-layer renders only that view layer (the others are disabled).
Exit status: 0 written, 2 bad arguments, 3 the render did not produce the file.
"""
import argparse
import os
import re
import sys
import time

import bpy


def parse_args(argv):
    argv = argv[argv.index("--") + 1:] if "--" in argv else []
    p = argparse.ArgumentParser(prog="blender -b FILE.blend -P proden_pass.py --")
    p.add_argument("--seed", type=int, required=True, help="Cycles seed, distinct per pass")
    p.add_argument("--spp", type=int, required=True, help="samples per pixel of this pass")
    p.add_argument("--frame", type=int, help="frame to render (default: the scene's current)")
    p.add_argument("--out", required=True, help="output .exr path; #### = padded frame number")
    p.add_argument("--scene", help="scene name (default: the active scene)")
    p.add_argument("--view-layer", help="render only this view layer")
    p.add_argument("--threads", type=int, default=0, help="render threads (0 = all cores)")
    p.add_argument("--res", type=int, help="override the resolution (square, tests)")
    p.add_argument("--half", action="store_true", help="16-bit half float instead of 32-bit")
    p.add_argument("--keep-format", action="store_true",
                   help="keep the .blend's OpenEXR settings (must be OPEN_EXR or _MULTILAYER)")
    p.add_argument("--no-denoising-data", action="store_true",
                   help="do not add the Denoising Data passes (proden then uses colour only)")
    a = p.parse_args(argv)
    if not a.out.lower().endswith(".exr"):
        p.error("--out must end in .exr")
    if a.spp < 1:
        p.error("--spp must be >= 1")
    return a


def expand_frame(path, frame):
    """Blender's #### padding: the last run of #s becomes the frame number, zero-padded."""
    runs = list(re.finditer(r"#+", path))
    if not runs:
        return path
    m = runs[-1]
    return path[:m.start()] + "%0*d" % (len(m.group(0)), frame) + path[m.end():]


def configure(scene, a):
    if scene.render.engine != "CYCLES":
        sys.stderr.write("proden_pass: scene %s renders with %s; proden passes need Cycles\n"
                         % (scene.name, scene.render.engine))
        sys.exit(2)
    cy = scene.cycles
    cy.seed = a.seed
    cy.use_animated_seed = False
    cy.samples = a.spp
    cy.sample_offset = 0
    cy.use_adaptive_sampling = False
    cy.time_limit = 0.0
    cy.use_denoising = False
    cy.use_preview_denoising = False
    if a.view_layer:
        names = [vl.name for vl in scene.view_layers]
        if a.view_layer not in names:
            sys.stderr.write("proden_pass: no view layer %r (have: %s)\n"
                             % (a.view_layer, ", ".join(names)))
            sys.exit(2)
        for vl in scene.view_layers:
            vl.use = vl.name == a.view_layer
    if not a.no_denoising_data:
        for vl in scene.view_layers:
            vl.cycles.denoising_store_passes = True
    r = scene.render
    if a.res:
        r.resolution_x = r.resolution_y = a.res
        r.resolution_percentage = 100
    r.threads_mode = "FIXED" if a.threads > 0 else "AUTO"
    if a.threads > 0:
        r.threads = a.threads
    im = r.image_settings
    if a.keep_format:
        if im.file_format not in ("OPEN_EXR", "OPEN_EXR_MULTILAYER"):
            sys.stderr.write("proden_pass: --keep-format needs an OpenEXR output, the scene "
                             "writes %s\n" % im.file_format)
            sys.exit(2)
    else:
        im.file_format = "OPEN_EXR_MULTILAYER"
        im.exr_codec = "ZIP"
        im.color_depth = "16" if a.half else "32"
    r.use_file_extension = False
    r.use_overwrite = True
    r.use_placeholder = False


def main():
    a = parse_args(sys.argv)
    scene = bpy.data.scenes[a.scene] if a.scene else bpy.context.scene
    if a.scene and bpy.context.window is not None:
        bpy.context.window.scene = scene
    configure(scene, a)
    frame = a.frame if a.frame is not None else scene.frame_current
    scene.frame_set(frame)
    out = os.path.abspath(expand_frame(a.out, frame))
    os.makedirs(os.path.dirname(out), exist_ok=True)
    tmp = os.path.join(os.path.dirname(out), "." + os.path.basename(out) + ".partial")
    scene.render.filepath = tmp
    t0 = time.time()
    bpy.ops.render.render(write_still=True, scene=scene.name)
    dt = time.time() - t0
    if not os.path.isfile(tmp) or os.path.getsize(tmp) == 0:
        sys.stderr.write("proden_pass: the render did not write %s\n" % tmp)
        sys.exit(3)
    os.replace(tmp, out)
    print("PRODEN_PASS seed=%d spp=%d frame=%d seconds=%.3f out=%s"
          % (a.seed, a.spp, frame, dt, out), flush=True)


main()
