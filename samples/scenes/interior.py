"""Indirect-only interior for proden samples (Blender 3.4 Cycles, built from scratch).

A closed room (5 x 6 x 2.7 m; the camera is inside, the world is black) lit by a single
small area light that hangs behind the camera and faces the wall behind it. The camera
never sees the light nor the patch of wall it lights directly: everything in the frame is
lit by light that has bounced at least once (the lit back wall acts as a large, dim
secondary source), so low-spp passes are very noisy and converge slowly. Furniture: a
table, a sofa-like block, a bookcase, a glossy red sphere, a rough metal cylinder and a
rough-glossy (varnished) floor that reflects the indirect light.

    blender -b --factory-startup -noaudio -P samples/scenes/interior.py -- \
        --seed S --spp N --res 128 --out PATH.exr [--half]
"""

import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import common  # noqa: E402


def build(scene, args):
    plaster = common.principled("plaster", (0.8, 0.78, 0.74), roughness=1.0, specular=0.0)
    accent = common.principled("accent_wall", (0.25, 0.42, 0.55), roughness=1.0, specular=0.0)
    floor_mat = common.principled("varnished_wood", (0.42, 0.25, 0.12), roughness=0.3,
                                  specular=0.5)
    table_mat = common.principled("table", (0.6, 0.55, 0.45), roughness=0.8, specular=0.2)
    sofa_mat = common.principled("sofa", (0.55, 0.12, 0.1), roughness=1.0, specular=0.0)
    shelf_mat = common.principled("bookcase", (0.15, 0.3, 0.15), roughness=0.9, specular=0.1)
    red_gloss = common.principled("red_gloss", (0.7, 0.05, 0.04), roughness=0.12, specular=0.8)
    metal = common.principled("brushed_metal", (0.9, 0.8, 0.65), roughness=0.25, metallic=1.0)

    # Room: x in [-2.5, 2.5], y in [-3, 3] (front wall y = -3 is behind the camera),
    # z in [0, 2.7]. Normals point inwards.
    X, Y, Z = 2.5, 3.0, 2.7
    walls = [
        ("floor", [(-X, -Y, 0), (X, -Y, 0), (X, Y, 0), (-X, Y, 0)], floor_mat),
        ("ceiling", [(-X, -Y, Z), (-X, Y, Z), (X, Y, Z), (X, -Y, Z)], plaster),
        ("far_wall", [(-X, Y, 0), (X, Y, 0), (X, Y, Z), (-X, Y, Z)], accent),
        ("front_wall", [(-X, -Y, 0), (-X, -Y, Z), (X, -Y, Z), (X, -Y, 0)], plaster),
        ("left_wall", [(-X, -Y, 0), (-X, Y, 0), (-X, Y, Z), (-X, -Y, Z)], plaster),
        ("right_wall", [(X, -Y, 0), (X, -Y, Z), (X, Y, Z), (X, Y, 0)], plaster),
    ]
    for name, verts, mat in walls:
        common.flat_mesh(name, verts, [(0, 1, 2, 3)], mat)

    # Table: top + 4 legs.
    tx, ty = 0.3, 0.8
    common.box("table_top", (1.4, 0.8, 0.05), (tx, ty, 0.75), 10.0, table_mat)
    for i, (dx, dy) in enumerate([(-0.6, -0.32), (0.6, -0.32), (0.6, 0.32), (-0.6, 0.32)]):
        c, s = math.cos(math.radians(10.0)), math.sin(math.radians(10.0))
        common.box("table_leg%d" % i, (0.06, 0.06, 0.73), (tx + c * dx - s * dy, ty + s * dx + c * dy,
                                                     0.365), 10.0, table_mat)

    common.ico_sphere("red_sphere", 0.18, (tx - 0.3, ty, 0.955), red_gloss)
    common.cylinder("metal_can", 0.1, 0.0, 0.35, 24, metal, (tx + 0.35, ty + 0.1, 0.775))

    # Sofa-like block (seat + back) against the left wall, bookcase against the far wall.
    common.box("sofa_seat", (0.9, 2.0, 0.45), (-2.0, 0.6, 0.225), 0.0, sofa_mat)
    common.box("sofa_back", (0.25, 2.0, 0.5), (-2.33, 0.6, 0.7), 0.0, sofa_mat)
    common.box("bookcase", (1.4, 0.4, 2.0), (1.3, 2.75, 1.0), 0.0, shelf_mat)
    common.ico_sphere("metal_ball", 0.35, (1.5, -0.3, 0.35), metal)

    # The only light: a small area light behind the camera, facing the front wall (-y),
    # 0.65 m from it. One-sided, so it is invisible from the room (glossy objects see its
    # unlit back side); only the front wall (y < -2.35) lies in front of its plane.
    light = common.area_light("hidden_light", "SQUARE", 0.5, 150.0, (1.0, 0.88, 0.7),
                              (0.0, -2.35, 1.9))
    common.look_at(light, (0.0, -3.0, 1.9))

    cd = bpy.data.cameras.new("camera")
    cd.lens = 20.0
    cd.sensor_width = 36.0
    cd.clip_start = 0.05
    cam = bpy.data.objects.new("camera", cd)
    cam.location = (1.2, -2.2, 1.55)
    scene.collection.objects.link(cam)
    common.look_at(cam, (-0.4, 1.5, 0.7))
    scene.camera = cam

    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = world


if __name__ == "__main__":
    common.run(build)
