"""Shared helpers for the proden sample scenes (Blender 3.4, Cycles, bpy).

Each scene script builds its scene from scratch (no .blend) and renders exactly one
*pass* of the frame:

    blender -b --factory-startup -noaudio -P samples/scenes/<scene>.py -- \
        --seed S --spp N --res 128 --out PATH.exr [--half]

Passes of one frame differ only in ``--seed`` (scene.cycles.seed); everything else is
fixed so that two passes are statistically independent estimates of the same image and
a pass rendered twice with the same seed is bit-identical (flat-shaded meshes only).
"""

import argparse
import math
import os
import sys
import time

import bpy


def parse_args(argv=None):
    """Parse the arguments after Blender's ``--`` separator."""
    if argv is None:
        argv = sys.argv
    argv = argv[argv.index("--") + 1:] if "--" in argv else []
    p = argparse.ArgumentParser(prog="blender -b --factory-startup -noaudio -P <scene>.py --")
    p.add_argument("--seed", type=int, required=True, help="Cycles seed (distinct per pass)")
    p.add_argument("--spp", type=int, required=True, help="samples per pixel of this pass")
    p.add_argument("--res", type=int, default=128, help="square resolution in pixels")
    p.add_argument("--out", help="output path, must end in .exr (required unless --save-blend)")
    p.add_argument("--half", action="store_true", help="write half float (16 bit) instead of 32 bit")
    p.add_argument("--threads", type=int, default=0, help="render threads (0 = all cores)")
    p.add_argument("--save-blend", metavar="PATH",
                   help="save the configured scene as a .blend instead of rendering (farm tests "
                        "render it with deploy/blender/proden_pass.py)")
    a = p.parse_args(argv)
    if a.save_blend:
        if a.out:
            p.error("--save-blend and --out exclude each other")
    elif not a.out or not a.out.lower().endswith(".exr"):
        p.error("--out must end in .exr")
    if a.spp < 1 or a.res < 1:
        p.error("--spp and --res must be >= 1")
    return a


def reset_scene():
    """Remove every object, mesh, material, light and camera of the factory startup file."""
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj, do_unlink=True)
    for coll in (bpy.data.meshes, bpy.data.materials, bpy.data.lights, bpy.data.cameras,
                 bpy.data.worlds, bpy.data.images):
        for block in list(coll):
            coll.remove(block)
    return bpy.context.scene


def flat_mesh(name, verts, faces, material=None, location=(0, 0, 0)):
    """Create a flat-shaded mesh object (smooth shading is not bit-reproducible in 3.4)."""
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.update()
    for poly in me.polygons:
        poly.use_smooth = False
    obj = bpy.data.objects.new(name, me)
    obj.location = location
    if material is not None:
        me.materials.append(material)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def box(name, size, location, rot_z, mat):
    """Flat-shaded axis box of `size` (x, y, z) centred at `location`, turned rot_z degrees."""
    sx, sy, sz = (s / 2.0 for s in size)
    v = [(-sx, -sy, -sz), (sx, -sy, -sz), (sx, sy, -sz), (-sx, sy, -sz),
         (-sx, -sy, sz), (sx, -sy, sz), (sx, sy, sz), (-sx, sy, sz)]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    obj = flat_mesh(name, v, f, mat, location)
    obj.rotation_euler = (0, 0, math.radians(rot_z))
    return obj


def make_flat(obj):
    """Force flat shading on an object created by a bpy.ops primitive."""
    for poly in obj.data.polygons:
        poly.use_smooth = False
    return obj


def ico_sphere(name, radius, location, mat, subdivisions=4):
    """Flat-shaded icosphere with material `mat`."""
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=subdivisions, radius=radius,
                                          location=location)
    obj = make_flat(bpy.context.active_object)
    obj.name = name
    obj.data.materials.append(mat)
    return obj


def cylinder(name, radius, z0, z1, n, mat, location):
    """Closed n-gon prism from z0 to z1 (flat-shaded), normals outwards."""
    v = []
    for z in (z0, z1):
        for i in range(n):
            a = 2.0 * math.pi * i / n
            v.append((radius * math.cos(a), radius * math.sin(a), z))
    f = [tuple(reversed(range(n))), tuple(range(n, 2 * n))]
    for i in range(n):
        j = (i + 1) % n
        f.append((i, j, n + j, n + i))
    return flat_mesh(name, v, f, mat, location)


def area_light(name, shape, size, energy, color, location, spread=None):
    """Area light object (one-sided, facing its local -z) linked to the scene."""
    ld = bpy.data.lights.new(name, type="AREA")
    ld.shape = shape
    ld.size = size
    if spread is not None:
        ld.spread = spread
    ld.energy = energy
    ld.color = color
    light = bpy.data.objects.new(name, ld)
    light.location = location
    bpy.context.scene.collection.objects.link(light)
    return light


def principled(name, color, roughness=0.5, metallic=0.0, specular=0.5):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Specular"].default_value = specular
    return mat


def look_at(obj, target):
    """Point an object's -Z axis (camera/light forward) at ``target``."""
    from mathutils import Vector
    direction = Vector(target) - obj.location
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def configure_render(scene, args, clamp_indirect=0.0):
    """Fixed Cycles settings shared by all sample scenes (Blender 3.4)."""
    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.feature_set = "SUPPORTED"
    cy.shading_system = False          # SVM, not OSL
    cy.seed = args.seed
    cy.use_animated_seed = False
    cy.samples = args.spp
    cy.sample_offset = 0
    cy.use_adaptive_sampling = False   # 3.4 default is adaptive on: would vary spp per pixel
    cy.time_limit = 0.0
    cy.use_denoising = False           # Debian's Blender has no OIDN: denoising on fails
    cy.use_preview_denoising = False
    cy.use_preview_adaptive_sampling = False
    patterns = [i.identifier for i in cy.bl_rna.properties["sampling_pattern"].enum_items]
    if "PROGRESSIVE_MULTI_JITTER" in patterns:
        cy.sampling_pattern = "PROGRESSIVE_MULTI_JITTER"
    cy.scrambling_distance = 1.0       # < 1 correlates pixels
    cy.auto_scrambling_distance = False
    cy.use_fast_gi = False
    cy.use_guiding = False             # path guiding (3.4, CPU) learns across samples: keep off
    cy.direct_light_sampling_type = "MULTIPLE_IMPORTANCE_SAMPLING"
    cy.light_sampling_threshold = 0.01
    # No direct clamping. An indirect clamp (per scene) biases the estimator, but identically
    # for every pass and the reference (it is per sample), so references stay the expectation
    # of what the passes estimate.
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = clamp_indirect
    cy.blur_glossy = 0.0
    # Caustic paths (diffuse -> glossy -> small light) are fireflies that even a 2048 spp
    # reference does not converge at 128 px; off keeps references usable as ground truth.
    cy.caustics_reflective = False
    cy.caustics_refractive = False
    cy.max_bounces = 12
    cy.diffuse_bounces = 4
    cy.glossy_bounces = 4
    cy.transmission_bounces = 12
    cy.transparent_max_bounces = 8
    cy.volume_bounces = 0
    cy.pixel_filter_type = "BLACKMAN_HARRIS"
    cy.filter_width = 1.5
    cy.use_auto_tile = False
    if hasattr(cy, "use_light_tree"):  # 3.5+; absent in 3.4
        cy.use_light_tree = False

    r = scene.render
    r.resolution_x = args.res
    r.resolution_y = args.res
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.use_border = False
    r.film_transparent = False
    r.use_persistent_data = False
    r.threads_mode = "FIXED" if args.threads > 0 else "AUTO"
    if args.threads > 0:
        r.threads = args.threads
    scene.frame_set(1)

    # Linear scene-referred data goes into the EXR; view transform only affects display.
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0

    vl = scene.view_layers[0]
    vl.use_pass_combined = True
    vl.use_pass_z = False
    vl.cycles.denoising_store_passes = True     # Denoising Albedo / Normal / Depth
    if hasattr(vl.cycles, "pass_debug_sample_count"):
        vl.cycles.pass_debug_sample_count = True  # Debug Sample Count.X

    im = r.image_settings
    im.file_format = "OPEN_EXR_MULTILAYER"
    im.exr_codec = "ZIP"
    im.color_depth = "16" if args.half else "32"
    im.color_mode = "RGBA"
    im.use_preview = False
    r.use_file_extension = False       # write exactly --out, no extension games
    r.use_overwrite = True
    r.use_placeholder = False          # no zero-byte placeholder files
    r.use_stamp = False                # no burn-in; metadata below is still written
    r.use_stamp_note = True
    r.stamp_note_text = "proden sample seed=%d spp=%d" % (args.seed, args.spp)
    return scene


def render_pass(scene, args):
    """Render one pass to a temporary name, then rename atomically onto --out."""
    out = os.path.abspath(args.out)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    tmp = out + ".partial"
    scene.render.filepath = tmp
    t0 = time.time()
    bpy.ops.render.render(write_still=True)
    dt = time.time() - t0
    if not os.path.isfile(tmp) or os.path.getsize(tmp) == 0:
        sys.stderr.write("proden: render did not write %s\n" % tmp)
        sys.exit(2)
    os.replace(tmp, out)
    print("PRODEN_RENDER seed=%d spp=%d res=%d half=%d seconds=%.3f out=%s"
          % (args.seed, args.spp, args.res, int(args.half), dt, out), flush=True)
    return dt


def run(build_scene, clamp_indirect=0.0):
    """Entry point for a scene script: parse args, build, configure, render, quit."""
    args = parse_args()
    scene = reset_scene()
    build_scene(scene, args)
    configure_render(scene, args, clamp_indirect=clamp_indirect)
    save_or_render(scene, args)


def save_or_render(scene, args):
    """--save-blend: save the configured scene (farm tools render it); else render --out."""
    if args.save_blend:
        path = os.path.abspath(args.save_blend)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        bpy.ops.wm.save_as_mainfile(filepath=path, compress=False)
        print("PRODEN_SAVED %s" % path, flush=True)
        return
    render_pass(scene, args)
