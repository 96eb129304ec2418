#!/usr/bin/python3
"""Write samples/renders/MANIFEST.json from the render logs (render_times.tsv) of each set.

    /usr/bin/python3 samples/make_manifest.py

Needs blender, povray and oiiotool on PATH (for versions and channel lists).
"""

import csv
import json
import os
import re
import subprocess

HERE = os.path.dirname(os.path.abspath(__file__))
RENDERS = os.path.join(HERE, "renders")


def run(cmd):
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        return r.stdout + r.stderr
    except (OSError, subprocess.TimeoutExpired):
        return ""


def blender_version():
    m = re.search(r"Blender (\S+)", run(["blender", "-b", "--factory-startup", "--version"]))
    return m.group(1) if m else None


def povray_version():
    m = re.search(r"POV-Ray (\S+)", run(["povray", "--version"]))
    return m.group(1) if m else None


def image_info(path):
    """Resolution, channel names and per-channel pixel types from `oiiotool --info -v`."""
    out = subprocess.run(["oiiotool", "--info", "-v", path], capture_output=True, text=True).stdout
    info = {}
    m = re.search(r":\s+(\d+)\s+x\s+(\d+),\s+(\d+) channel,\s+(\S+)\s+(\S+)", out)
    if m:
        info["resolution"] = [int(m.group(1)), int(m.group(2))]
        types = m.group(4).split("/")
        n = int(m.group(3))
        info["pixel_types"] = types if len(types) == n else types * n
        info["format"] = m.group(5)
    m = re.search(r"channel list: (.*)", out)
    if m:
        info["channels"] = [c.strip() for c in m.group(1).split(",")]
    return info


def read_log(d):
    with open(os.path.join(d, "render_times.tsv")) as f:
        return list(csv.DictReader(f, delimiter="\t"))


def cycles_set(name, script, bver):
    d = os.path.join(RENDERS, name)
    rows = read_log(d)
    last = {r["file"]: r for r in rows}          # re-renders append; keep the latest line
    passes = sorted(k for k in last if k.startswith("pass_"))
    ref = last.get("reference.exr")
    p0 = image_info(os.path.join(d, passes[0]))
    return {
        "renderer": "cycles",
        "renderer_version": "Blender " + (bver or "?"),
        "scene_script": "samples/scenes/" + script,
        "render_command": "samples/render_cycles.sh %s samples/renders/%s %d %s %s%s" % (
            script[:-3], name, len(passes), last[passes[0]]["spp"], ref["spp"] if ref else 0,
            " --half" if last[passes[0]]["half"] == "1" else ""),
        "resolution": p0.get("resolution"),
        "pass_channels": p0.get("channels"),
        "pass_pixel_types": p0.get("pixel_types"),
        "passes": [{"file": k, "seed": int(last[k]["seed"]), "spp": int(last[k]["spp"]),
                    "half": last[k]["half"] == "1", "wall_seconds": float(last[k]["wall_s"]),
                    "render_seconds": float(last[k]["render_s"])} for k in passes],
        "reference": None if ref is None else {
            "file": "reference.exr", "seed": int(ref["seed"]), "spp": int(ref["spp"]),
            "half": False, "wall_seconds": float(ref["wall_s"]),
            "render_seconds": float(ref["render_s"])},
        "notes": "wall_seconds: whole blender process (startup + sync + render + write); "
                 "render_seconds: bpy.ops.render.render() call. CPU, 2 cores.",
    }


def povray_set(name, pver):
    d = os.path.join(RENDERS, name)
    last = {r["file"]: r for r in read_log(d)}
    passes = sorted(k for k in last if k.startswith("pass_") and k.endswith(".exr"))
    ref = last.get("reference.exr")
    p0 = image_info(os.path.join(d, passes[0]))
    s = {
        "renderer": "povray",
        "renderer_version": "POV-Ray " + (pver or "?"),
        "scene_script": "samples/povray/scene.pov",
        "scene_include": "samples/povray/proden_pass.inc",
        "render_command": "samples/render_povray.sh samples/renders/%s %d %d" % (
            name, len(passes), int(ref["spp"]) if ref else 0),
        "resolution": p0.get("resolution"),
        "pass_channels": p0.get("channels"),
        "pass_pixel_types": p0.get("pixel_types"),
        "seeding": "Declare=Pass=<pass>; the scene hashes Pass into seed() (proden_pass.inc); "
                   "1 sample per pixel per pass; 'seed' below is the pass number",
        "passes": [{"file": k, "seed": int(last[k]["pass"]), "spp": 1, "half": True,
                    "wall_seconds": float(last[k]["wall_s"])} for k in passes],
        "extra": [],
        "reference": None,
    }
    if "pass_00.hdr" in last:
        r = last["pass_00.hdr"]
        s["extra"].append({"file": "pass_00.hdr", "seed": int(r["pass"]), "spp": 1,
                           "format": "Radiance HDR (RGBE), same pass as pass_00.exr",
                           "wall_seconds": float(r["wall_s"])})
    if ref:
        a, b = ref["pass"].split("..")
        s["reference"] = {"file": "reference.exr", "seeds": [int(a), int(b)],
                          "spp": int(ref["spp"]), "half": False,
                          "method": "float32 mean of POV-Ray passes %s..%s (1 spp each, half EXR) "
                                    "computed with oiiotool --add / --divc" % (a, b),
                          "wall_seconds": float(ref["wall_s"])}
    return s


def main():
    bver, pver = blender_version(), povray_version()
    manifest = {
        "description": "proden sample passes (independent renders of one frame) and references; "
                       "see samples/README.md",
        "machine": "Debian 12, 2 cores, CPU rendering",
        "sets": {},
    }
    for name, script in (("cornell", "cornell.py"), ("textured_dof", "textured_dof.py")):
        if os.path.isfile(os.path.join(RENDERS, name, "render_times.tsv")):
            manifest["sets"][name] = cycles_set(name, script, bver)
    if os.path.isfile(os.path.join(RENDERS, "povray", "render_times.tsv")):
        manifest["sets"]["povray"] = povray_set("povray", pver)
    out = os.path.join(RENDERS, "MANIFEST.json")
    with open(out + ".tmp", "w") as f:
        json.dump(manifest, f, indent=2)
        f.write("\n")
    os.replace(out + ".tmp", out)
    print("wrote", out)


if __name__ == "__main__":
    main()
