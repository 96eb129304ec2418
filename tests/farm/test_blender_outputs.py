"""Blender output conventions a TD expects, on real Cycles renders (Debian's Blender): a .blend
with two view layers (BG, ViewLayer) and the Depth, Mist, Diffuse Color, Object Index and
Cryptomatte passes, rendered as proden passes with deploy/blender/proden_pass.py.

- the view layer: the alphabetically first is taken and said so; --view-layer chooses; a missing
  one is refused naming the layers the file has;
- a single-layer OPEN_EXR file carrying cycles.<layer>.samples is Cycles with the header's spp;
- AOVs: Combined.A, Depth, Mist, DiffCol are spp-weighted means of the passes (checked against the
  passes' own pixels), Cryptomatte and IndexOB come from the first pass unchanged, Cryptomatte's
  header entries travel along with their name pointed at the written channels;
- #### frame padding in proden_pass.py's --out."""
import json
import os
import subprocess
import sys
import tempfile
import unittest

import numpy as np
import OpenImageIO as oiio

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", ".."))
BINARY = os.environ.get("PRODEN_BINARY", os.path.join(REPO, "build", "proden"))
BLENDER = os.environ.get("BLENDER", "blender")

SETUP = """
import bpy
s = bpy.context.scene
vl = s.view_layers[0]
vl.use_pass_z = True
vl.use_pass_mist = True
vl.use_pass_diffuse_color = True
vl.use_pass_object_index = True
vl.use_pass_cryptomatte_object = True
s.view_layers.new("BG")
bpy.ops.wm.save_as_mainfile(filepath=%r)
"""


def channels(path):
    inp = oiio.ImageInput.open(path)
    spec = inp.spec()
    data = inp.read_image(0, 0, 0, spec.nchannels, "float")
    attrs = {a.name: a.value for a in spec.extra_attribs}
    names = list(spec.channelnames)
    inp.close()
    return {n: data[:, :, i] for i, n in enumerate(names)}, attrs


class BlenderOutputs(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = tempfile.TemporaryDirectory(prefix="proden-blender-")
        t = cls.tmp.name
        base = os.path.join(t, "cornell.blend")
        subprocess.run([BLENDER, "-b", "--factory-startup", "-noaudio", "-P",
                        os.path.join(REPO, "samples", "scenes", "cornell.py"), "--", "--seed", "1",
                        "--spp", "1", "--res", "32", "--save-blend", base],
                       check=True, capture_output=True, timeout=300)
        cls.blend = os.path.join(t, "aov.blend")
        with open(os.path.join(t, "setup.py"), "w") as f:
            f.write(SETUP % cls.blend)
        subprocess.run([BLENDER, "-b", base, "-noaudio", "-P", os.path.join(t, "setup.py")],
                       check=True, capture_output=True, timeout=300)
        cls.passes = []
        for k, spp in enumerate((4, 4, 8)):
            out = os.path.join(t, "pass_%02d" % k, "beauty_####.exr")
            cls.render("--seed", str(k + 1), "--spp", str(spp), "--frame", "7", "--out", out)
            cls.passes.append(out.replace("####", "0007"))
        cls.single = os.path.join(t, "single", "beauty_0007.exr")
        cls.render("--seed", "9", "--spp", "4", "--frame", "7", "--out", cls.single,
                   "--keep-format")

    @classmethod
    def render(cls, *args):
        if "--keep-format" in args:  # switch the .blend to single-layer OPEN_EXR first
            expr = ("import bpy; s=bpy.context.scene; s.render.image_settings.file_format="
                    "'OPEN_EXR'; s.render.image_settings.color_depth='32'")
            cmd = [BLENDER, "-b", cls.blend, "-noaudio", "--python-expr", expr]
        else:
            cmd = [BLENDER, "-b", cls.blend, "-noaudio"]
        r = subprocess.run(cmd + ["-P", os.path.join(REPO, "deploy", "blender", "proden_pass.py"),
                                  "--", "--threads", "1"] + list(args),
                           capture_output=True, text=True, timeout=300)
        assert "PRODEN_PASS" in r.stdout, r.stdout[-2000:] + r.stderr[-2000:]

    @classmethod
    def tearDownClass(cls):
        cls.tmp.cleanup()

    def proden(self, *args):
        return subprocess.run([BINARY] + list(args), capture_output=True, text=True, timeout=300)

    def test_frame_padding(self):
        for p in self.passes:
            self.assertTrue(os.path.exists(p), p)

    def test_single_layer_open_exr_is_cycles(self):
        r = self.proden("info", "--json", self.single)
        self.assertEqual(r.returncode, 0, r.stderr)
        info = json.loads(r.stdout)[0]
        self.assertEqual(info["renderer"], "cycles")
        self.assertEqual((info["spp"], info["spp_source"]), (4, "header"))
        self.assertEqual(info["layers"], ["BG", "ViewLayer"])
        self.assertEqual(info["aovs"], ["A"])

    def test_view_layer_choice(self):
        out = os.path.join(self.tmp.name, "bg.exr")
        r = self.proden("denoise", "-q", "--json", "--out", out, *self.passes)
        self.assertEqual(r.returncode, 0, r.stderr)
        j = json.loads(r.stdout)
        self.assertEqual(j["view_layer"], "BG")  # the alphabetically first ...
        self.assertIn("view layers BG, ViewLayer; reading BG", r.stderr)  # ... and said so
        self.assertEqual(j["view_layers"], ["BG", "ViewLayer"])
        r = self.proden("denoise", "-q", "--view-layer", "Nope", "--out", out, *self.passes)
        self.assertEqual(r.returncode, 3)
        self.assertIn("no view layer 'Nope' (the file has: BG, ViewLayer)", r.stderr)

    def test_aovs_means_and_pass_through(self):
        out = os.path.join(self.tmp.name, "vl.exr")
        r = self.proden("denoise", "-q", "--json", "--view-layer", "ViewLayer", "--out", out,
                        *self.passes)
        self.assertEqual(r.returncode, 0, r.stderr)
        modes = {a["name"]: a["mode"] for a in json.loads(r.stdout)["aovs"]}
        for name in ("A", "Depth.Z", "Mist.Z", "DiffCol.R"):
            self.assertEqual(modes[name], "mean", name)
        for name in ("CryptoObject00.r", "CryptoObject00.a", "IndexOB.X"):
            self.assertEqual(modes[name], "first_pass", name)
        self.assertNotIn("Denoising Albedo.R", modes)  # a feature, not an AOV
        got, attrs = channels(out)
        inputs = [channels(p)[0] for p in self.passes]
        weights = np.array([4.0, 4.0, 8.0])
        for name in ("Depth.Z", "Mist.Z", "DiffCol.G"):
            want = sum(w * c["ViewLayer." + name] for w, c in zip(weights, inputs)) / weights.sum()
            np.testing.assert_allclose(got[name], want, rtol=1e-5, atol=1e-6, err_msg=name)
        want_a = sum(w * c["ViewLayer.Combined.A"] for w, c in zip(weights, inputs)) / weights.sum()
        np.testing.assert_allclose(got["A"], want_a, rtol=1e-5, atol=1e-6)
        for name in ("CryptoObject00.r", "CryptoObject01.g", "IndexOB.X"):
            np.testing.assert_array_equal(got[name], inputs[0]["ViewLayer." + name], name)
        crypto = {k: v for k, v in attrs.items() if k.startswith("cryptomatte/")}
        names = [v for k, v in crypto.items() if k.endswith("/name")]
        self.assertEqual(names, ["CryptoObject"])
        self.assertTrue(any(k.endswith("/manifest") for k in crypto))
        self.assertEqual(attrs["proden:view_layer"], "ViewLayer")
        e = json.loads(attrs["proden:estimated_error"])
        self.assertEqual(e["noise_scope"], "pixel")
        self.assertEqual(e["spp"], 16)


if __name__ == "__main__":
    unittest.main()
