"""Render a bundled Cycles sample scene at a non-square resolution (default 1920x1080) for the
harness's "one more Cycles sample per pixel" cost. Same CLI and settings as samples/scenes/*.py
(common.py), with the resolution overridden after common.configure_render:

    PRODEN_SCENE=cornell PRODEN_W=1920 PRODEN_H=1080 \
      blender -b --factory-startup -noaudio -P bench/cycles_frame.py -- \
        --seed 1 --spp 1 --res 1920 --out /tmp/f.exr

Blender's `cycles.ViewLayer.render_time` header of the result is path-tracing time only (no
start-up, scene sync or BVH build).
"""
import importlib.util
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "samples", "scenes")
sys.path.insert(0, SCENES)
import common  # noqa: E402

name = os.environ.get("PRODEN_SCENE", "cornell")
spec = importlib.util.spec_from_file_location("proden_scene", os.path.join(SCENES, name + ".py"))
mod = importlib.util.module_from_spec(spec)
spec.loader.exec_module(mod)  # defines build(); its __main__ block does not run
_configure = common.configure_render


def configure(scene, args, clamp_indirect=0.0):
    _configure(scene, args, clamp_indirect=clamp_indirect)
    scene.render.resolution_x = int(os.environ.get("PRODEN_W", "1920"))
    scene.render.resolution_y = int(os.environ.get("PRODEN_H", "1080"))
    scene.render.resolution_percentage = 100


common.configure_render = configure
common.run(mod.build)
