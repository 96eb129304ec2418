"""Random procedural scene for the learned-mixer training data (Blender 3.4, Cycles CPU).

The scene is a deterministic function of --scene-seed (Python random.Random(seed)); several
*chunks* (independent passes of the same frame) are rendered in one Blender process:

    blender -b --factory-startup -noaudio -P training/scenes/procedural.py -- \
        --scene-seed N --res 128 --chunk SEED:SPP:OUT.exr [--chunk SEED:SPP:OUT.exr ...]

Each chunk sets scene.cycles.seed=SEED and samples=SPP and writes a float32 multilayer EXR with
the same layout as samples/scenes/common.py (Combined + Denoising Albedo/Normal/Depth), so
`proden` reads it with the cycles profile. Adaptive sampling, Cycles denoising and clamping
are off. Scene variety: random primitives on a floor (+ walls), materials from Blender's
bundled material library and generated Principled BSDFs (glass, metal, finely textured
diffuse), a random bundled HDRI world (random strength/rotation, sometimes dim), random
area/point/sun/spot lights, sometimes a small bright light behind glass with caustics on
(fireflies), random camera, depth of field in ~1/3 of the scenes, random exposure; with
--room-prob P, a share P of the seeds is closed into a room lit only indirectly (build_room).
"""

import argparse
import glob
import math
import os
import random
import sys
import types

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "samples", "scenes"))
import bpy  # noqa: E402
from mathutils import Vector  # noqa: E402
import common  # noqa: E402  (samples/scenes/common.py: reset_scene, configure_render, ...)

MATLIB = "/usr/share/blender/scripts/addons/materials_library_vx/sample_materials.blend"
HDRI_DIR = "/usr/share/blender/datafiles/studiolights/world"
# Eevee-only / odd materials of the library that make no sense in Cycles renders.
MATLIB_SKIP = {"Fake Shading", "Fake Glass", "Crushed Velvet Eevee", "Double  Sided",
               "Stars", "Blaster Bolt (Blue)", "Glow Glass", "Fresnel", "Building"}


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="procedural.py")
    p.add_argument("--scene-seed", type=int, required=True)
    p.add_argument("--res", type=int, default=128)
    p.add_argument("--threads", type=int, default=0)
    p.add_argument("--chunk", action="append", default=[], help="SEED:SPP:OUT.exr")
    p.add_argument("--describe", action="store_true", help="print the scene description")
    p.add_argument("--room-prob", type=float, default=0.0,
                   help="probability of a closed room lit only indirectly (own RNG stream, so "
                        "0 leaves every seed's scene as before)")
    a = p.parse_args(argv)
    chunks = []
    for c in a.chunk:
        seed, spp, out = c.split(":", 2)
        if not out.lower().endswith(".exr") or int(spp) < 1:
            p.error("bad --chunk %s" % c)
        chunks.append((int(seed), int(spp), out))
    a.chunks = chunks
    return a


# ---------------------------------------------------------------- materials
def library_materials(rng):
    if not os.path.isfile(MATLIB):
        return []
    with bpy.data.libraries.load(MATLIB) as (src, dst):
        names = sorted(n for n in src.materials if n not in MATLIB_SKIP)
        dst.materials = rng.sample(names, min(len(names), 6))
    return [m for m in dst.materials if m is not None]


def rand_color(rng, lo=0.05, hi=0.9):
    return (rng.uniform(lo, hi), rng.uniform(lo, hi), rng.uniform(lo, hi))


def glass_mat(rng, name):
    mat = common.principled(name, (1.0, 1.0, 1.0), roughness=0.0)
    b = mat.node_tree.nodes["Principled BSDF"]
    tint = (1.0, 1.0, 1.0) if rng.random() < 0.5 else rand_color(rng, 0.5, 1.0)
    b.inputs["Base Color"].default_value = (*tint, 1.0)
    b.inputs["Transmission"].default_value = 1.0
    b.inputs["Roughness"].default_value = 0.0 if rng.random() < 0.7 else rng.uniform(0.02, 0.2)
    b.inputs["IOR"].default_value = rng.uniform(1.33, 1.6)
    return mat


def metal_mat(rng, name):
    return common.principled(name, rand_color(rng, 0.4, 1.0), roughness=rng.uniform(0.0, 0.25),
                             metallic=1.0)


def textured_mat(rng, name):
    mat = common.principled(name, (0.5, 0.5, 0.5), roughness=rng.uniform(0.3, 1.0),
                            specular=rng.uniform(0.0, 0.6))
    nt = mat.node_tree
    b = nt.nodes["Principled BSDF"]
    tc = nt.nodes.new("ShaderNodeTexCoord")
    kind = rng.choice(["noise", "voronoi", "checker", "brick", "wave"])
    if kind == "noise":
        t = nt.nodes.new("ShaderNodeTexNoise")
        t.inputs["Scale"].default_value = rng.uniform(15, 120)
        t.inputs["Detail"].default_value = rng.uniform(2, 12)
        fac = t.outputs["Fac"]
    elif kind == "voronoi":
        t = nt.nodes.new("ShaderNodeTexVoronoi")
        t.inputs["Scale"].default_value = rng.uniform(15, 80)
        fac = t.outputs["Distance"]
    elif kind == "checker":
        t = nt.nodes.new("ShaderNodeTexChecker")
        t.inputs["Scale"].default_value = rng.uniform(10, 60)
        fac = t.outputs["Fac"]
    elif kind == "brick":
        t = nt.nodes.new("ShaderNodeTexBrick")
        t.inputs["Scale"].default_value = rng.uniform(5, 30)
        fac = t.outputs["Fac"]
    else:
        t = nt.nodes.new("ShaderNodeTexWave")
        t.inputs["Scale"].default_value = rng.uniform(10, 60)
        t.inputs["Distortion"].default_value = rng.uniform(0, 8)
        fac = t.outputs["Fac"]
    nt.links.new(tc.outputs["Object" if rng.random() < 0.5 else "Generated"], t.inputs["Vector"])
    mix = nt.nodes.new("ShaderNodeMixRGB")
    mix.inputs["Color1"].default_value = (*rand_color(rng), 1.0)
    mix.inputs["Color2"].default_value = (*rand_color(rng), 1.0)
    nt.links.new(fac, mix.inputs["Fac"])
    nt.links.new(mix.outputs["Color"], b.inputs["Base Color"])
    if rng.random() < 0.4:
        bump = nt.nodes.new("ShaderNodeBump")
        bump.inputs["Strength"].default_value = rng.uniform(0.1, 0.6)
        nt.links.new(fac, bump.inputs["Height"])
        nt.links.new(bump.outputs["Normal"], b.inputs["Normal"])
    if rng.random() < 0.3:  # textured roughness: glossy/matte speckle
        nt.links.new(fac, b.inputs["Roughness"])
    return mat


def pick_material(rng, libmats, i):
    r = rng.random()
    if r < 0.25 and libmats:
        return rng.choice(libmats), "lib"
    if r < 0.40:
        return glass_mat(rng, "glass%d" % i), "glass"
    if r < 0.60:
        return metal_mat(rng, "metal%d" % i), "metal"
    if r < 0.70:
        return common.principled("plain%d" % i, rand_color(rng), roughness=rng.uniform(0.2, 1)), "plain"
    return textured_mat(rng, "tex%d" % i), "tex"


def pick_opaque(rng, libmats, i):
    """A floor/wall material: no glass (a glass floor shows the world below it)."""
    opaque = [m for m in libmats if "Glass" not in m.name and "Juice" not in m.name
              and "Bubble" not in m.name]
    for _ in range(20):
        r = rng.random()
        if r < 0.3 and opaque:
            return rng.choice(opaque), "lib"
        if r < 0.45:
            return metal_mat(rng, "metal%d" % i), "metal"
        if r < 0.6:
            return common.principled("plain%d" % i, rand_color(rng), roughness=rng.uniform(0.2, 1)), "plain"
        if r >= 0.6:
            return textured_mat(rng, "tex%d" % i), "tex"
    return common.principled("plain%d" % i, rand_color(rng), roughness=1.0), "plain"


def auto_exposure(scene, rng, probe_path, desc, probe_spp=16):
    """Set Cycles film exposure so the median luminance is 0.18 * 2^U(-2.5, 1.5).

    A 32x32, `probe_spp` probe render (fixed seed) measures the scene; film_exposure scales the
    Combined pass in the EXR (unlike the view transform's exposure). A room lit only indirectly
    needs more probe samples: at 16 spp most of its pixels are still near zero, the median reads
    low and the frame came out 5-10x brighter than the target."""
    import numpy as np
    target = 0.18 * 2.0 ** rng.uniform(-2.5, 1.5)
    cy = scene.cycles
    r = scene.render
    cy.seed, cy.samples = 4242, probe_spp
    r.resolution_percentage = 25
    r.filepath = probe_path
    r.image_settings.file_format = "OPEN_EXR"   # single layer: loadable with pixels
    bpy.ops.render.render(write_still=True)
    r.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    r.image_settings.color_depth = "32"
    r.resolution_percentage = 100
    img = bpy.data.images.load(probe_path)
    px = np.array(img.pixels[:], dtype=np.float64).reshape(-1, 4)[:, :3]
    bpy.data.images.remove(img)
    os.remove(probe_path)
    lum = px @ np.array([0.2126, 0.7152, 0.0722])
    med = float(np.median(lum))
    k = min(64.0, max(1.0 / 64.0, target / max(med, 1e-6)))
    cy.film_exposure = k
    desc["probe_median"] = round(med, 4)
    desc["film_exposure"] = round(k, 4)


# ---------------------------------------------------------------- geometry
def add_primitive(rng, kind, size, loc):
    ops = bpy.ops.mesh
    if kind == "cube":
        ops.primitive_cube_add(size=size, location=loc)
    elif kind == "sphere":
        ops.primitive_uv_sphere_add(radius=size / 2, segments=48, ring_count=24, location=loc)
    elif kind == "ico":
        ops.primitive_ico_sphere_add(radius=size / 2, subdivisions=rng.choice([1, 2, 4]), location=loc)
    elif kind == "cylinder":
        ops.primitive_cylinder_add(radius=size / 2, depth=size * rng.uniform(0.6, 2.0),
                                   vertices=rng.choice([6, 12, 48]), location=loc)
    elif kind == "cone":
        ops.primitive_cone_add(radius1=size / 2, depth=size * 1.3, vertices=32, location=loc)
    elif kind == "torus":
        ops.primitive_torus_add(major_radius=size / 2, minor_radius=size * rng.uniform(0.08, 0.2),
                                major_segments=48, minor_segments=16, location=loc)
    elif kind == "monkey":
        ops.primitive_monkey_add(size=size, location=loc)
    else:  # thin plane / panel
        ops.primitive_plane_add(size=size, location=loc)
    obj = bpy.context.active_object
    common.make_flat(obj)
    return obj


def build(scene, rng, desc):
    libmats = library_materials(rng)
    desc["library"] = [m.name for m in libmats]

    # floor and walls
    floor_mat, fk = pick_opaque(rng, libmats, 100) if rng.random() < 0.6 else (
        common.principled("floor", rand_color(rng, 0.2, 0.8), roughness=rng.uniform(0.3, 1.0)), "plain")
    bpy.ops.mesh.primitive_plane_add(size=40, location=(0, 0, 0))
    bpy.context.active_object.data.materials.append(floor_mat)
    desc["floor"] = fk

    # objects
    objs = []
    n = rng.randint(3, 8)
    kinds = ["cube", "sphere", "ico", "cylinder", "cone", "torus", "monkey", "plane"]
    for i in range(n):
        kind = rng.choice(kinds)
        size = rng.uniform(0.4, 1.4)
        r = rng.uniform(0, 2.2)
        a = rng.uniform(0, 2 * math.pi)
        z = size / 2 if rng.random() < 0.8 else size / 2 + rng.uniform(0.2, 1.2)
        obj = add_primitive(rng, kind, size, (r * math.cos(a), r * math.sin(a), z))
        if kind == "plane":
            obj.rotation_euler = (rng.uniform(0.8, 1.6), 0, rng.uniform(0, 6.3))
        else:
            obj.rotation_euler = (rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), rng.uniform(0, 6.3))
        mat, mk = pick_material(rng, libmats, i)
        obj.data.materials.append(mat)
        objs.append((obj, mk, size))
        desc.setdefault("objects", []).append([kind, mk, round(size, 2)])
    return objs, libmats


def build_walls(rng, libmats, cam_az, desc):
    """0-2 walls behind the objects as seen from the camera (never between camera and objects)."""
    nwalls = rng.choice([0, 0, 1, 2])
    for w in range(nwalls):
        wm, _ = pick_opaque(rng, libmats, 200 + w) if rng.random() < 0.5 else (
            common.principled("wall%d" % w, rand_color(rng, 0.2, 0.8), roughness=1.0), "plain")
        ang = cam_az + math.pi + rng.uniform(-1.0, 1.0)
        d = rng.uniform(3.0, 5.0)
        bpy.ops.mesh.primitive_plane_add(size=30, location=(d * math.cos(ang), d * math.sin(ang), 0))
        wall = bpy.context.active_object
        wall.name = "openwall%d" % w
        wall.rotation_euler = (math.pi / 2, 0, ang + math.pi / 2)
        wall.data.materials.append(wm)
    desc["walls"] = nwalls


def build_room(scene, rng, libmats, cam_loc, expo, desc):
    """Close the scene into a room lit only indirectly, like a real interior lit through a
    cove: ceiling and four walls around the camera and the objects, and 1-3 area lights
    under the ceiling facing up, hidden from the camera, so every visible surface is lit by
    bounces (the low-light, high-variance regime of an interior at 1 spp per pass)."""
    half = max(abs(cam_loc[0]), abs(cam_loc[1]), 3.0) + rng.uniform(1.0, 3.0)
    height = max(cam_loc[2] + rng.uniform(0.8, 2.5), 3.0)
    wall_mat, wk = pick_opaque(rng, libmats, 300) if rng.random() < 0.4 else (
        common.principled("roomwall", rand_color(rng, 0.3, 0.9), roughness=1.0), "plain")
    ceil_mat = common.principled("ceiling", rand_color(rng, 0.6, 0.95), roughness=1.0)
    bpy.ops.mesh.primitive_plane_add(size=2 * half, location=(0, 0, height))
    bpy.context.active_object.data.materials.append(ceil_mat)
    for k in range(4):
        ang = k * math.pi / 2
        bpy.ops.mesh.primitive_plane_add(size=2 * max(half, height),
                                         location=(half * math.cos(ang), half * math.sin(ang), 0))
        wall = bpy.context.active_object
        wall.rotation_euler = (math.pi / 2, 0, ang + math.pi / 2)
        wall.data.materials.append(wall_mat)
    lights = []
    for i in range(rng.randint(1, 3)):
        a = rng.uniform(0, 2 * math.pi)
        r = rng.uniform(0.5, 0.9) * half
        loc = (r * math.cos(a), r * math.sin(a), height - rng.uniform(0.15, 0.6))
        power, size = rng.uniform(300, 3000), rng.uniform(0.3, 1.5)
        ob = add_light(scene, rng, "AREA", loc, power * expo, size,
                       (loc[0], loc[1], height + 1.0), "cove%d" % i)
        ob.visible_camera = False
        lights.append(["AREA_UP", round(power, 1), round(size, 2)])
    desc["room"] = {"half": round(half, 2), "height": round(height, 2), "wall": wk, "lights": lights}


# ---------------------------------------------------------------- lighting / camera
def build_world(scene, rng, expo, desc):
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    bg = nt.nodes["Background"]
    hdris = sorted(glob.glob(os.path.join(HDRI_DIR, "*.exr")))
    strength = rng.choice([rng.uniform(0.02, 0.15), rng.uniform(0.2, 1.0), rng.uniform(0.5, 2.0)])
    if hdris:
        path = rng.choice(hdris)
        env = nt.nodes.new("ShaderNodeTexEnvironment")
        env.image = bpy.data.images.load(path)
        tc = nt.nodes.new("ShaderNodeTexCoord")
        mp = nt.nodes.new("ShaderNodeMapping")
        mp.inputs["Rotation"].default_value = (0, 0, rng.uniform(0, 2 * math.pi))
        nt.links.new(tc.outputs["Generated"], mp.inputs["Vector"])
        nt.links.new(mp.outputs["Vector"], env.inputs["Vector"])
        nt.links.new(env.outputs["Color"], bg.inputs["Color"])
        desc["hdri"] = os.path.basename(path)
    else:
        bg.inputs["Color"].default_value = (0.5, 0.6, 0.8, 1.0)
    bg.inputs["Strength"].default_value = strength * expo
    desc["world_strength"] = round(strength, 3)


def add_light(scene, rng, kind, loc, power, size, target, name):
    ld = bpy.data.lights.new(name, kind)
    ld.energy = power
    if kind == "AREA":
        ld.size = size
    elif kind in ("POINT", "SPOT"):
        ld.shadow_soft_size = size
    elif kind == "SUN":
        ld.angle = math.radians(rng.uniform(0.5, 5))
    if kind == "SPOT":
        ld.spot_size = math.radians(rng.uniform(25, 70))
        ld.spot_blend = rng.uniform(0.05, 0.5)
    ob = bpy.data.objects.new(name, ld)
    ob.location = loc
    scene.collection.objects.link(ob)
    common.look_at(ob, target)
    return ob


def build_lights(scene, rng, objs, cam_loc, expo, desc):
    lights = []
    for i in range(rng.randint(1, 3)):
        kind = rng.choice(["AREA", "AREA", "POINT", "SUN", "SPOT"])
        a = rng.uniform(0, 2 * math.pi)
        r = rng.uniform(1.5, 5.0)
        loc = (r * math.cos(a), r * math.sin(a), rng.uniform(1.5, 5.0))
        if kind == "SUN":
            power, size = rng.uniform(0.5, 6.0), 0
        elif kind == "AREA":
            power, size = rng.uniform(50, 1500), rng.uniform(0.1, 2.0)
        elif kind == "POINT":
            power, size = rng.uniform(50, 1200), rng.uniform(0.02, 0.5)
        else:
            power, size = rng.uniform(200, 3000), rng.uniform(0.02, 0.3)
        add_light(scene, rng, kind, loc, power * expo, size, (0, 0, 0.3), "light%d" % i)
        lights.append([kind, round(power, 1), round(size, 2)])
    # small bright light behind glass (caustics, fireflies)
    glass = [(o, s) for o, k, s in objs if k == "glass"]
    caustics = False
    if glass and rng.random() < 0.5:
        o, s = rng.choice(glass)
        away = (o.location - Vector(cam_loc)).normalized()
        loc = o.location + away * (s * 0.5 + rng.uniform(0.2, 0.8)) + Vector((0, 0, rng.uniform(0.0, 0.8)))
        power = rng.uniform(100, 800)
        size = rng.uniform(0.03, 0.15)
        add_light(scene, rng, "POINT", tuple(loc), power * expo, size, tuple(o.location), "glasslight")
        lights.append(["POINT_BEHIND_GLASS", round(power, 1), round(size, 3)])
        caustics = True
    desc["lights"] = lights
    return caustics


def build_camera(scene, rng, objs, desc):
    cd = bpy.data.cameras.new("cam")
    cam = bpy.data.objects.new("cam", cd)
    scene.collection.objects.link(cam)
    scene.camera = cam
    cd.lens = rng.uniform(28, 70)
    # look at a point among the objects
    centre = Vector((0, 0, 0))
    for o, _, _ in objs:
        centre += o.location
    centre /= max(1, len(objs))
    target = centre.lerp(rng.choice(objs)[0].location, rng.uniform(0, 0.6))
    a = rng.uniform(0, 2 * math.pi)
    elev = math.radians(rng.uniform(8, 55))
    dist = rng.uniform(4.0, 8.0) * (cd.lens / 40.0)
    loc = target + Vector((dist * math.cos(a) * math.cos(elev), dist * math.sin(a) * math.cos(elev),
                           dist * math.sin(elev)))
    loc.z = max(loc.z, 0.3)
    cam.location = loc
    common.look_at(cam, tuple(target))
    dof = rng.random() < 1.0 / 3.0
    cd.dof.use_dof = dof
    if dof:
        focus = rng.choice(objs)[0].location
        cd.dof.focus_distance = (focus - loc).length
        cd.dof.aperture_fstop = rng.uniform(0.4, 2.8)
    desc["cam_az"] = a
    desc["camera"] = {"lens": round(cd.lens, 1), "dist": round(dist, 2), "dof": dof}
    return tuple(loc)


def main():
    args = parse_args()
    rng = random.Random(args.scene_seed)
    desc = {"scene_seed": args.scene_seed}
    scene = common.reset_scene()
    objs, libmats = build(scene, rng, desc)
    cam_loc = build_camera(scene, rng, objs, desc)
    build_walls(rng, libmats, desc.pop("cam_az"), desc)
    expo = 2.0 ** rng.uniform(-2.0, 2.0)       # random exposure: scales every light source
    desc["exposure"] = round(expo, 3)
    build_world(scene, rng, expo, desc)
    caustics = build_lights(scene, rng, objs, cam_loc, expo, desc)
    room_rng = random.Random(args.scene_seed * 7919 + 17)   # its own stream: see --room-prob
    if room_rng.random() < args.room_prob:
        # The room replaces the open scene's lights and walls (a wall could hide every cove
        # light from the camera's side): only the hidden lights light it.
        for ob in [o for o in bpy.data.objects
                   if o.type == "LIGHT" or o.name.startswith("openwall")]:
            bpy.data.objects.remove(ob, do_unlink=True)
        scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
        build_room(scene, room_rng, libmats, cam_loc, expo, desc)
        caustics = False

    cfg = types.SimpleNamespace(seed=1, spp=1, res=args.res, out="x.exr", half=False,
                                threads=args.threads)
    common.configure_render(scene, cfg, clamp_indirect=0.0)
    cy = scene.cycles
    cy.max_bounces = 8
    cy.diffuse_bounces = 4
    cy.glossy_bounces = 4
    cy.transmission_bounces = 8
    cy.transparent_max_bounces = 8
    cy.caustics_reflective = caustics
    cy.caustics_refractive = caustics
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    desc["caustics"] = caustics
    if args.chunks:
        auto_exposure(scene, rng, os.path.abspath(args.chunks[0][2]) + ".probe.exr", desc,
                      probe_spp=256 if "room" in desc else 16)
    print("PRODEN_SCENE %r" % (desc,), flush=True)

    # Keep the synchronised scene between chunks: only the seed and sample count change, and
    # re-synchronising costs ~0.8 s per chunk (more than rendering a 16 spp chunk at 128 px).
    scene.render.use_persistent_data = os.environ.get("PRODEN_PERSISTENT", "1") == "1"
    for seed, spp, out in args.chunks:
        cy.seed = seed
        cy.samples = spp
        assert not cy.use_adaptive_sampling and not cy.use_denoising
        scene.render.stamp_note_text = "proden training scene=%d seed=%d spp=%d" % (
            args.scene_seed, seed, spp)
        common.render_pass(scene, types.SimpleNamespace(seed=seed, spp=spp, res=args.res,
                                                        half=False, out=out))


main()
