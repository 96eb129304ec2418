"""Glass and caustics for proden samples (Blender 3.4 Cycles, built from scratch).

A flat-shaded glass sphere, a rotated glass box and a tinted "glass of liquid" (a glass
cylinder filled with a lower-IOR liquid) stand on a diffuse floor in front of a diffuse
back wall. The only strong light is a small, bright area light above and behind the objects;
the world is dim. Unlike the other sample scenes, reflective and refractive caustics are ON
and nothing is clamped: the floor under and beside the glass is lit only by
diffuse -> glass -> light paths that path tracing finds by BSDF sampling, so low-spp passes
are full of fireflies. The light is large enough (0.3 m at ~3 m) that the caustics converge
(slowly) rather than staying a speckle forever.

    blender -b --factory-startup -noaudio -P samples/scenes/glass.py -- \
        --seed S --spp N --res 128 --out PATH.exr [--half]
"""

import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import common  # noqa: E402


def glass_material(name, ior, color=(1.0, 1.0, 1.0), roughness=0.0):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    out = nt.nodes["Material Output"]
    nt.nodes.remove(nt.nodes["Principled BSDF"])
    glass = nt.nodes.new("ShaderNodeBsdfGlass")
    glass.distribution = "GGX"   # sharp (roughness 0) -> singular refraction
    glass.inputs["Color"].default_value = (*color, 1.0)
    glass.inputs["Roughness"].default_value = roughness
    glass.inputs["IOR"].default_value = ior
    nt.links.new(glass.outputs["BSDF"], out.inputs["Surface"])
    return mat


def build(scene, args):
    floor_mat = common.principled("floor", (0.7, 0.68, 0.62), roughness=1.0, specular=0.0)
    wall_mat = common.principled("wall", (0.45, 0.5, 0.6), roughness=1.0, specular=0.0)
    glass = glass_material("glass", 1.5)
    glass_box_mat = glass_material("glass_box", 1.5, color=(0.85, 0.95, 1.0))
    liquid = glass_material("liquid", 1.33, color=(1.0, 0.75, 0.35))

    G = 6.0
    common.flat_mesh("floor", [(-G, -G, 0), (G, -G, 0), (G, G, 0), (-G, G, 0)],
                     [(0, 1, 2, 3)], floor_mat)
    common.flat_mesh("back_wall", [(-G, 2.0, 0), (G, 2.0, 0), (G, 2.0, 3), (-G, 2.0, 3)],
                     [(0, 1, 2, 3)], wall_mat)

    common.ico_sphere("glass_sphere", 0.5, (-0.55, 0.1, 0.5), glass, subdivisions=5)

    common.box("glass_box", (0.55, 0.55, 0.7), (0.55, 0.55, 0.35), 35.0, glass_box_mat)

    # "Glass of liquid": a solid glass prism with a tinted, lower-IOR liquid prism inside
    # (nested surfaces, not physically exact interfaces, but refractive and coloured).
    cx, cy = 0.35, -0.55
    common.cylinder("tumbler_outer", 0.22, 0.0, 0.55, 32, glass, (cx, cy, 0))
    common.cylinder("liquid", 0.19, 0.03, 0.40, 32, liquid, (cx, cy, 0))

    # Small bright area light behind, left of and above the objects (outside the frame),
    # pointing at them: the shadows and caustics fall forward-right, towards the camera.
    # (spread 80 degrees keeps the grazing back wall out of the beam)
    key = common.area_light("key", "DISK", 0.3, 70.0, (1.0, 0.95, 0.85), (-1.3, 1.1, 3.4),
                            spread=math.radians(80.0))
    common.look_at(key, (0.2, -0.5, 0.0))

    cd = bpy.data.cameras.new("camera")
    cd.lens = 35.0
    cd.sensor_width = 36.0
    cam = bpy.data.objects.new("camera", cd)
    cam.location = (0.4, -3.4, 1.7)
    scene.collection.objects.link(cam)
    common.look_at(cam, (0.0, 0.0, 0.35))
    scene.camera = cam

    world = bpy.data.worlds.new("dim")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.5, 0.6, 0.8, 1.0)
    bg.inputs["Strength"].default_value = 0.03
    scene.world = world


def main():
    args = common.parse_args()
    scene = common.reset_scene()
    build(scene, args)
    common.configure_render(scene, args, clamp_indirect=0.0)
    cy = scene.cycles
    # The point of this scene: caustics on, no clamping, no glossy filter.
    cy.caustics_reflective = True
    cy.caustics_refractive = True
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    cy.blur_glossy = 0.0
    cy.transmission_bounces = 16
    cy.max_bounces = 16
    common.save_or_render(scene, args)


if __name__ == "__main__":
    main()
