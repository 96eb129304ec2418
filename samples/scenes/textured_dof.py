"""Fine procedural textures + depth of field under a sky (Blender 3.4 Cycles, from scratch).

High-frequency detail a denoiser tends to smear: a brick/noise ground plane, a checker-
and-wave textured wall, a Voronoi-textured block, a glossy sphere; a thin-lens camera
(f/0.9) focused on the middle object so foreground and background are blurred; the world
is a procedural Nishita sky (no HDRI file needed) plus a Sun light.

    blender -b --factory-startup -noaudio -P samples/scenes/textured_dof.py -- \
        --seed S --spp N --res 128 --out PATH.exr [--half]
"""

import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import common  # noqa: E402


def textured_material(name, kind, scale, roughness=0.5):
    """Principled BSDF whose base colour (and roughness) come from a procedural texture."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = roughness
    coord = nt.nodes.new("ShaderNodeTexCoord")
    if kind == "brick":
        tex = nt.nodes.new("ShaderNodeTexBrick")
        tex.inputs["Color1"].default_value = (0.55, 0.18, 0.08, 1)
        tex.inputs["Color2"].default_value = (0.35, 0.25, 0.15, 1)
        tex.inputs["Mortar"].default_value = (0.8, 0.8, 0.75, 1)
        tex.inputs["Mortar Size"].default_value = 0.05
        tex.inputs["Scale"].default_value = scale
        noise = nt.nodes.new("ShaderNodeTexNoise")
        noise.inputs["Scale"].default_value = scale * 8.0
        noise.inputs["Detail"].default_value = 8.0
        mix = nt.nodes.new("ShaderNodeMixRGB")
        mix.blend_type = "MULTIPLY"
        mix.inputs["Fac"].default_value = 0.6
        nt.links.new(coord.outputs["Object"], tex.inputs["Vector"])
        nt.links.new(coord.outputs["Object"], noise.inputs["Vector"])
        nt.links.new(tex.outputs["Color"], mix.inputs["Color1"])
        nt.links.new(noise.outputs["Color"], mix.inputs["Color2"])
        nt.links.new(mix.outputs["Color"], bsdf.inputs["Base Color"])
        nt.links.new(tex.outputs["Fac"], bsdf.inputs["Roughness"])
    elif kind == "checker_wave":
        tex = nt.nodes.new("ShaderNodeTexChecker")
        tex.inputs["Color1"].default_value = (0.9, 0.9, 0.85, 1)
        tex.inputs["Color2"].default_value = (0.05, 0.05, 0.08, 1)
        tex.inputs["Scale"].default_value = scale
        wave = nt.nodes.new("ShaderNodeTexWave")
        wave.inputs["Scale"].default_value = scale * 0.7
        wave.inputs["Distortion"].default_value = 4.0
        wave.inputs["Detail"].default_value = 4.0
        mix = nt.nodes.new("ShaderNodeMixRGB")
        mix.blend_type = "OVERLAY"
        mix.inputs["Fac"].default_value = 0.5
        nt.links.new(coord.outputs["Object"], tex.inputs["Vector"])
        nt.links.new(coord.outputs["Object"], wave.inputs["Vector"])
        nt.links.new(tex.outputs["Color"], mix.inputs["Color1"])
        nt.links.new(wave.outputs["Color"], mix.inputs["Color2"])
        nt.links.new(mix.outputs["Color"], bsdf.inputs["Base Color"])
    elif kind == "voronoi":
        tex = nt.nodes.new("ShaderNodeTexVoronoi")
        tex.feature = "F1"
        tex.inputs["Scale"].default_value = scale
        ramp = nt.nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].color = (0.02, 0.15, 0.05, 1)
        ramp.color_ramp.elements[1].color = (0.8, 0.7, 0.3, 1)
        nt.links.new(coord.outputs["Object"], tex.inputs["Vector"])
        nt.links.new(tex.outputs["Distance"], ramp.inputs["Fac"])
        mix = nt.nodes.new("ShaderNodeMixRGB")
        mix.blend_type = "MULTIPLY"
        mix.inputs["Fac"].default_value = 1.0
        nt.links.new(ramp.outputs["Color"], mix.inputs["Color1"])
        nt.links.new(tex.outputs["Color"], mix.inputs["Color2"])
        nt.links.new(mix.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def build(scene, args):
    ground_mat = textured_material("ground_brick", "brick", 6.0, roughness=0.6)
    wall_mat = textured_material("wall_checker", "checker_wave", 24.0, roughness=0.4)
    block_mat = textured_material("block_voronoi", "voronoi", 30.0, roughness=0.3)
    chrome = common.principled("chrome", (0.9, 0.9, 0.9), roughness=0.05, metallic=1.0)

    G = 8.0
    common.flat_mesh("ground", [(-G, -G, 0), (G, -G, 0), (G, G, 0), (-G, G, 0)],
                     [(0, 1, 2, 3)], ground_mat)
    common.flat_mesh("wall", [(-4, 3, 0), (4, 3, 0), (4, 3, 2.5), (-4, 3, 2.5)],
                     [(0, 1, 2, 3)], wall_mat)

    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(0.0, 0.0, 0.4),
                                    rotation=(0, 0, math.radians(30)))
    block = common.make_flat(bpy.context.active_object)
    block.name = "focus_block"
    block.data.materials.append(block_mat)

    common.ico_sphere("chrome_sphere", 0.45, (-1.1, 1.6, 0.45), chrome, subdivisions=5)

    common.ico_sphere("near_sphere", 0.25, (0.6, -1.6, 0.25), wall_mat)

    cd = bpy.data.cameras.new("camera")
    cd.lens = 50.0
    cd.sensor_width = 36.0
    cd.dof.use_dof = True
    cd.dof.aperture_fstop = 0.9
    cd.dof.aperture_blades = 0
    cam = bpy.data.objects.new("camera", cd)
    cam.location = (0.9, -3.6, 1.0)
    scene.collection.objects.link(cam)
    common.look_at(cam, (0.0, 0.0, 0.4))
    cd.dof.focus_distance = (cam.location - block.location).length
    scene.camera = cam

    world = bpy.data.worlds.new("sky")
    world.use_nodes = True
    nt = world.node_tree
    sky = nt.nodes.new("ShaderNodeTexSky")
    sky.sky_type = "NISHITA"
    sky.sun_elevation = math.radians(35.0)
    sky.sun_rotation = math.radians(200.0)
    sky.sun_disc = False   # the sun is a separate, explicitly sampled Sun light (below):
    # a 2 degree sun disk inside the world texture is found mostly by BSDF sampling -> fireflies
    sky.altitude = 0.0
    sky.air_density = 1.0
    sky.dust_density = 1.0
    sky.ozone_density = 1.0
    bg = nt.nodes["Background"]
    bg.inputs["Strength"].default_value = 0.05
    nt.links.new(sky.outputs["Color"], bg.inputs["Color"])
    scene.world = world
    world.cycles.sampling_method = "AUTOMATIC"

    sd = bpy.data.lights.new("sun", type="SUN")
    sd.angle = math.radians(2.0)
    sd.energy = 5.0
    sd.color = (1.0, 0.9, 0.75)
    sun = bpy.data.objects.new("sun", sd)
    # elevation 35 deg, to the right of and behind the camera (light shines along local -Z)
    sun.rotation_euler = (math.radians(90.0 - 35.0), 0.0, math.radians(60.0))
    scene.collection.objects.link(sun)


if __name__ == "__main__":
    # Sun glints seen through glossy bounces are fireflies that a 2048 spp reference does not
    # converge: clamp indirect samples (same clamp for passes and reference).
    common.run(build, clamp_indirect=10.0)
