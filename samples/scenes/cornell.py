"""Cornell-box-like interior for proden samples (Blender 3.4 Cycles, built from scratch).

A closed box (the camera sits inside, so no light leaks in), a small ceiling area light,
red/green side walls, a glossy metal sphere, a rough-glossy tall block and a diffuse
short block: mostly indirect light, so a few spp are very noisy.

    blender -b --factory-startup -noaudio -P samples/scenes/cornell.py -- \
        --seed S --spp N --res 128 --out PATH.exr [--half]
"""

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bpy  # noqa: E402
import common  # noqa: E402


def build(scene, args):
    white = common.principled("white", (0.73, 0.73, 0.73), roughness=1.0, specular=0.0)
    red = common.principled("red", (0.63, 0.065, 0.05), roughness=1.0, specular=0.0)
    green = common.principled("green", (0.14, 0.45, 0.091), roughness=1.0, specular=0.0)
    metal = common.principled("metal", (0.95, 0.85, 0.6), roughness=0.08, metallic=1.0)
    glossy = common.principled("glossy_blue", (0.1, 0.2, 0.6), roughness=0.25, specular=0.8)

    # Box interior: x in [-1, 1], y in [-1, 1] (back wall at y = +1), z in [0, 2].
    # Normals point inwards. The front wall (y = -1.2) closes the box behind the camera.
    W, F = 1.0, -1.2
    walls = [
        ("floor", [(-W, F, 0), (W, F, 0), (W, W, 0), (-W, W, 0)], white),
        ("ceiling", [(-W, F, 2), (-W, W, 2), (W, W, 2), (W, F, 2)], white),
        ("back", [(-W, W, 0), (W, W, 0), (W, W, 2), (-W, W, 2)], white),
        ("front", [(-W, F, 0), (-W, F, 2), (W, F, 2), (W, F, 0)], white),
        ("left", [(-W, F, 0), (-W, W, 0), (-W, W, 2), (-W, F, 2)], red),
        ("right", [(W, F, 0), (W, F, 2), (W, W, 2), (W, W, 0)], green),
    ]
    for name, verts, mat in walls:
        common.flat_mesh(name, verts, [(0, 1, 2, 3)], mat)

    common.box("tall_block", (0.55, 0.55, 1.2), (-0.35, 0.35, 0.6), 18.0, glossy)
    common.box("short_block", (0.55, 0.55, 0.55), (0.4, -0.15, 0.275), -17.0, white)

    common.ico_sphere("metal_sphere", 0.3, (0.42, -0.15, 0.85), metal)

    # Small area light just below the ceiling, facing down.
    common.area_light("ceiling_light", "SQUARE", 0.35, 12.0, (1.0, 0.85, 0.65),
                      (0.0, 0.45, 1.995))

    cd = bpy.data.cameras.new("camera")
    cd.lens = 20.0
    cd.sensor_width = 36.0
    cd.clip_start = 0.05
    cam = bpy.data.objects.new("camera", cd)
    cam.location = (0.0, -1.15, 1.0)
    common.look_at(cam, (0.0, 0.5, 0.95))
    scene.collection.objects.link(cam)
    scene.camera = cam

    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = world


if __name__ == "__main__":
    common.run(build)
