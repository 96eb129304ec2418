"""The daemon publishes frames the way `proden denoise` writes them (one pipeline object, one
vocabulary, one publish path): the published EXR carries the `proden:` provenance header and the
`mixvariance` layer, a job's `pipeline.denoiser` is honoured, and the CLI run with the same options
on the same passes writes the same header and the same result. Real daemon, real CLI, stdlib only."""
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
import unittest

sys.path.insert(0, os.path.dirname(__file__))
from harness import SharedDaemonTest, BINARY, CORNELL, Daemon, TempRoot, metric  # noqa: E402

HEADER_FIELDS = ["proden:passes", "proden:spp", "proden:inputs", "proden:denoiser", "proden:mixer",
                 "proden:mixer_weights", "proden:divergence", "proden:t_test",
                 "proden:variance_source", "proden:low_confidence", "proden:estimated_mse",
                 "proden:estimated_mse_source"]
LAYERS = ["render", "variance", "denoised", "alpha", "sure", "mixvariance"]
# The error estimate's cross-validation layers: written when it cross-validated (two passes and
# a denoiser that does not read the halves itself: docs/error_estimate.md).
CV_LAYERS = ["cvsquare", "cvvariance"]


# OpenEXR's compression attribute values (file layout spec).
NONE, ZIP, PIZ = 0, 3, 4


def exr_header(data):
    """Parses a single-part OpenEXR header: {name: (type, raw bytes)} (OpenEXR file layout spec)."""
    if data[:4] != b"\x76\x2f\x31\x01":
        raise AssertionError("not an OpenEXR file")
    pos, attrs = 8, {}
    while True:
        end = data.index(b"\0", pos)
        name, pos = data[pos:end].decode(), end + 1
        if not name:
            return attrs
        end = data.index(b"\0", pos)
        typ, pos = data[pos:end].decode(), end + 1
        (size,) = struct.unpack_from("<i", data, pos)
        attrs[name] = (typ, data[pos + 4:pos + 4 + size])
        pos += 4 + size


def strings(attrs):
    return {k: v.decode() for k, (t, v) in attrs.items() if t == "string"}


def channels(attrs):
    """Channel names of a `chlist` attribute: name NUL, then 16 bytes per channel; NUL ends it."""
    raw, pos, names = attrs["channels"][1], 0, []
    while raw[pos:pos + 1] != b"\0":
        end = raw.index(b"\0", pos)
        names.append(raw[pos:end].decode())
        pos = end + 1 + 16
    return names


class PublishCase(SharedDaemonTest):
    """A daemon, and the helpers that publish a frame and run the CLI on the same passes."""

    def publish(self, name, pipeline=None, passes=2, **extra):
        """A job fed CORNELL[0..passes-1] by upload; returns (job id, frame status, EXR bytes)."""
        if pipeline is not None:
            extra["pipeline"] = pipeline
        jid = self.d.create_job(name, **extra)
        for k, path in enumerate(CORNELL[:passes]):
            with open(path, "rb") as f:
                s, b = self.d.json("PUT", "/api/v1/jobs/%s/frames/1/passes/%s" % (jid, "abcdefgh"[k]),
                                   f.read())
            self.assertEqual(s, 202, b)
        self.d.wait_passes(jid, 1, passes)
        s, status = self.d.frame(jid, 1)
        self.assertEqual(s, 200, status)
        s, _, exr = self.d.request("GET", "/api/v1/jobs/%s/frames/1/image?format=exr" % jid)
        self.assertEqual(s, 200)
        return jid, status, exr

    def cli(self, flags, out, passes=2):
        """`proden denoise --aov` on the same passes; returns its --json summary."""
        r = subprocess.run([BINARY, "denoise", "-q", "--aov", "--json", "--out", out] + flags +
                           CORNELL[:passes], capture_output=True, timeout=120)
        self.assertEqual(r.returncode, 0, r.stderr)
        return json.loads(r.stdout)

    def assert_same_result(self, a, b):
        """`proden eval` of one file against the other: their results are identical."""
        r = subprocess.run([BINARY, "eval", "--json", "--ref", a, b], capture_output=True,
                           timeout=60)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertEqual(json.loads(r.stdout)["results"][0]["rmse"], 0.0)



class PublishTest(PublishCase):
    """What every published frame carries, per option (the ThreadSanitizer tree runs this class:
    tests/CMakeLists.txt)."""

    def test_default_job_publishes_provenance_and_mixvariance_like_the_cli(self):
        jid, status, exr = self.publish("pub_default")
        attrs = exr_header(exr)
        hdr = strings(attrs)
        for k in HEADER_FIELDS:
            self.assertIn(k, hdr)
        self.assertTrue(hdr["Software"].startswith("proden "))
        self.assertEqual(hdr["proden:passes"], "2")
        self.assertEqual(hdr["proden:denoiser"], "nlmeans")
        self.assertEqual(hdr["proden:inputs"], "HDR+ALB+NRM+DEP")
        chans = channels(attrs)
        for layer in LAYERS + CV_LAYERS:
            for c in "RGB":
                self.assertIn("%s.%s" % (layer, c), chans)
        # The header's estimated error is the frame status's, to the last bit.
        self.assertEqual(float(hdr["proden:estimated_mse"]), status["estimated_mse"])
        self.assertEqual(hdr["proden:estimated_mse_source"], status["estimated_mse_source"])
        self.assertEqual(status["estimated_error"]["mse"], status["estimated_mse"])
        self.assertEqual(status["estimated_error"]["source"], "variance+cross-validation")
        self.assertEqual(json.loads(hdr["proden:estimated_error"]), status["estimated_error"])
        s, h, png = self.d.request(
            "GET", "/api/v1/jobs/%s/frames/1/image?format=png&layer=mixvariance" % jid)
        self.assertEqual((s, png[:8]), (200, b"\x89PNG\r\n\x1a\n"))

        # The CLI on the same passes with the same (default) options: same header, same layers,
        # same result, same estimated error.
        with tempfile.TemporaryDirectory() as tmp:
            published = os.path.join(tmp, "daemon.exr")
            with open(published, "wb") as f:
                f.write(exr)
            out = os.path.join(tmp, "cli.exr")
            summary = self.cli([], out)
            with open(out, "rb") as f:
                cli_attrs = exr_header(f.read())
            cli_hdr = strings(cli_attrs)
            for k in HEADER_FIELDS + ["Software"]:
                self.assertEqual(cli_hdr[k], hdr[k], k)
            # auto: the CLI writes PIZ; the daemon writes none, then PIZ once it is idle.
            self.assertEqual(cli_attrs["compression"], ("compression", bytes([PIZ])))
            self.assertIn(attrs["compression"][1], (bytes([NONE]), bytes([PIZ])))
            self.assertEqual(sorted(channels(cli_attrs)), sorted(chans))
            self.assertEqual(summary["estimated_mse"], status["estimated_mse"])
            self.assertEqual(summary["estimated_mse_source"], status["estimated_mse_source"])
            self.assertEqual(summary["estimated_error"], status["estimated_error"])
            self.assert_same_result(published, out)

    def test_output_compression(self):
        """auto (the default): the version is published uncompressed and the same file becomes
        PIZ, with the same values, once the daemon has been idle for a second; a job's
        output.compression is what its published EXR says, echoed in the job; a lossy or unknown
        one is refused naming the field."""
        jid, status, exr = self.publish("pub_auto")
        url = "/api/v1/jobs/%s/frames/1/image?format=exr" % jid
        self.assertEqual(exr_header(exr)["compression"], ("compression", bytes([NONE])))
        s, job = self.d.json("GET", "/api/v1/jobs/" + jid)
        self.assertEqual((s, job["output"]["compression"]), (200, "auto"))
        deadline = time.time() + 60
        while True:
            s, h, later = self.d.request("GET", url)
            self.assertEqual(s, 200)
            if exr_header(later)["compression"][1] == bytes([PIZ]) or time.time() > deadline:
                break
            time.sleep(0.2)
        self.assertEqual(exr_header(later)["compression"], ("compression", bytes([PIZ])))
        self.assertLess(len(later), len(exr))
        self.assertEqual(h["etag"], 'W/"v%d"' % status["version"])  # same version, other bytes
        self.assertEqual(strings(exr_header(later)), strings(exr_header(exr)))
        with tempfile.TemporaryDirectory() as tmp:
            a, b = os.path.join(tmp, "a.exr"), os.path.join(tmp, "b.exr")
            for path, data in ((a, exr), (b, later)):
                with open(path, "wb") as f:
                    f.write(data)
            self.assert_same_result(a, b)
        self.assertGreaterEqual(metric(self.d, "proden_publish_compressed_later_total"), 1)
        out = os.path.join(self.d.allowed, "pub_zip_out")
        jid, _, exr = self.publish("pub_zip", output={"dir": out, "compression": "zip"})
        self.assertEqual(exr_header(exr)["compression"], ("compression", bytes([ZIP])))
        s, job = self.d.json("GET", "/api/v1/jobs/" + jid)
        self.assertEqual((s, job["output"]["compression"]), (200, "zip"))
        for bad in ("dwaa", "b44", 4):
            s, b = self.d.json("POST", "/api/v1/jobs",
                               {"name": "pub_bad", "output": {"dir": out, "compression": bad}})
            self.assertEqual(s, 400, b)
            self.assertIn("output.compression", b["error"]["message"])

    def test_job_denoiser_gaussian_is_honoured(self):
        jid, status, exr = self.publish("pub_gauss", {"denoiser": "gaussian", "tile": 64})
        hdr = strings(exr_header(exr))
        self.assertEqual(hdr["proden:denoiser"], "gaussian")
        self.assertEqual(hdr["proden:inputs"], "HDR")  # the Gaussian reads no features
        s, job = self.d.json("GET", "/api/v1/jobs/" + jid)
        self.assertEqual(job["pipeline"], {"denoiser": "gaussian", "mixer": "auto", "tile": 64})
        with tempfile.TemporaryDirectory() as tmp:
            published = os.path.join(tmp, "daemon.exr")
            with open(published, "wb") as f:
                f.write(exr)
            out = os.path.join(tmp, "cli.exr")
            summary = self.cli(["--denoiser", "gaussian", "--tile", "64"], out)
            self.assertEqual(summary["pipeline"]["denoiser"], "gaussian")
            self.assertEqual(summary["estimated_mse"], status["estimated_mse"])
            self.assert_same_result(published, out)
            # ... and it is not what the default denoiser publishes.
            default = os.path.join(tmp, "default.exr")
            self.cli([], default)
            r = subprocess.run([BINARY, "eval", "--json", "--ref", published, default],
                               capture_output=True, timeout=60)
            self.assertGreater(json.loads(r.stdout)["results"][0]["rmse"], 0.0)

    def test_job_denoiser_none_publishes_the_render(self):
        jid, status, exr = self.publish("pub_none", {"denoiser": "none"})
        attrs = exr_header(exr)
        hdr = strings(attrs)
        self.assertEqual(hdr["proden:denoiser"], "none")
        self.assertEqual(hdr["proden:estimated_mse_source"], "variance")
        self.assertEqual(status["estimated_error"]["source"], "variance")
        self.assertNotIn("mixvariance.R", channels(attrs))
        self.assertNotIn("cvsquare.R", channels(attrs))
        s, b = self.d.json("GET", "/api/v1/jobs/%s/frames/1/image?format=png&layer=mixvariance" % jid)
        self.assertEqual((s, b["error"]["code"]), (404, "layer_not_available"))

    def test_pipeline_options_are_validated_by_name(self):
        for pipeline, field in (({"tile": 4}, "pipeline.tile"),
                                ({"frobnicate": 1}, "pipeline.frobnicate"),
                                ({"weights": "/etc/passwd"}, "pipeline.weights"),
                                ({"t_test": "no"}, "pipeline.t_test"),
                                ({"mixer": "stein", "closed_form_rule": "inverse-error"},
                                 "pipeline.closed_form_rule"),
                                ({"denoiser": "magic"}, "pipeline.denoiser")):
            s, b = self.d.json("POST", "/api/v1/jobs", {
                "name": "bad", "output": {"dir": self.d.allowed}, "pipeline": pipeline})
            self.assertEqual(s, 400, (pipeline, b))
            self.assertEqual(b["error"]["code"], "invalid_field")
            self.assertTrue(b["error"]["message"].startswith(field + ": "), b)


class NforPublishTest(PublishCase):
    """NFOR through the daemon equals the CLI's NFOR, number for number. The pipeline's numbers,
    not the daemon's concurrency: 3 of the TSan daemon's 3.5 minutes here, so the Release tree
    alone runs it."""

    def test_job_denoiser_nfor_publishes_what_the_cli_writes_under_both_mixers(self):
        """NFOR end to end through the daemon: the job's `pipeline.denoiser` "nfor" (the registry
        entry that asks the accumulator for the half buffers) under the closed-form mixer and the
        network; the published frame is bit-identical to `proden denoise --denoiser nfor` on the
        same passes, and is not NL-means' frame."""
        with tempfile.TemporaryDirectory() as tmp:
            default = os.path.join(tmp, "default.exr")
            self.cli([], default)
            for mixer, prefix in (("closed-form", "closed-form-"), ("network", "network-w")):
                with self.subTest(mixer=mixer):
                    jid, status, exr = self.publish("pub_nfor_" + mixer,
                                                    {"denoiser": "nfor", "mixer": mixer})
                    hdr = strings(exr_header(exr))
                    self.assertEqual(hdr["proden:denoiser"], "nfor")
                    self.assertEqual(hdr["proden:inputs"], "HDR+ALB+NRM+DEP")
                    self.assertEqual(hdr["proden:divergence"], "analytic")  # its hat diagonal
                    self.assertTrue(hdr["proden:mixer"].startswith(prefix), hdr["proden:mixer"])
                    # Two passes fill no quarters: the half runs are NFOR without halves.
                    self.assertEqual(status["estimated_error"]["source"],
                                     "variance+cross-validation")
                    published = os.path.join(tmp, "daemon_%s.exr" % mixer)
                    with open(published, "wb") as f:
                        f.write(exr)
                    out = os.path.join(tmp, "cli_%s.exr" % mixer)
                    summary = self.cli(["--denoiser", "nfor", "--mixer", mixer], out)
                    self.assertEqual(summary["pipeline"]["denoiser"], "nfor")
                    with open(out, "rb") as f:
                        cli_hdr = strings(exr_header(f.read()))
                    for k in HEADER_FIELDS:
                        self.assertEqual(cli_hdr[k], hdr[k], k)
                    self.assertEqual(summary["estimated_mse"], status["estimated_mse"])
                    self.assert_same_result(published, out)
                    r = subprocess.run([BINARY, "eval", "--json", "--ref", published, default],
                                       capture_output=True, timeout=60)
                    self.assertEqual(r.returncode, 0, r.stderr)
                    self.assertGreater(json.loads(r.stdout)["results"][0]["rmse"], 0.0)

    def test_job_denoiser_nfor_is_cross_validated_on_quarters_like_the_cli(self):
        """From 4 passes the daemon's NFOR frame keeps its halves' own halves (quarters) and
        cross-validates NFOR on them (docs/error_estimate.md); the estimate is the CLI's on the
        same passes, number for number."""
        with tempfile.TemporaryDirectory() as tmp:
            jid, status, exr = self.publish("pub_nfor_q", {"denoiser": "nfor"}, passes=4)
            est = status["estimated_error"]
            self.assertEqual(est["source"], "variance+cross-validation")
            self.assertIn("cvsquare.R", channels(exr_header(exr)))
            summary = self.cli(["--denoiser", "nfor"], os.path.join(tmp, "cli.exr"), passes=4)
            for k in ("source", "mse", "relmse", "equivalent_spp", "mse_high"):
                self.assertEqual(summary["estimated_error"][k], est[k], k)


if __name__ == "__main__":
    unittest.main(verbosity=2)
