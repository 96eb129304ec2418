#!/usr/bin/python3
"""CI check of the benchmark harness on tiny inputs (ctest -L bench): fails if a tool breaks.

  bench/check_harness.py BIN_DIR SAMPLES_DIR
"""
import json
import math
import os
import subprocess
import sys
import tempfile


def fail(msg):
    print("check_harness: FAIL:", msg, file=sys.stderr)
    sys.exit(1)


def finite(v):
    return isinstance(v, (int, float)) and math.isfinite(v)


def main():
    if len(sys.argv) != 3:
        fail("usage: check_harness.py BIN_DIR SAMPLES_DIR")
    bindir, samples = sys.argv[1], sys.argv[2]
    with tempfile.TemporaryDirectory() as d:
        js = os.path.join(d, "perf.json")
        out = subprocess.run([os.path.join(bindir, "proden_bench_pipeline"), "--width", "64",
                              "--height", "48", "--no-mc", "--no-4k", "--cycles-spp-seconds", "1",
                              "--repeat", "3", "--json", js, "--tmp", d],
                             capture_output=True, text=True)
        print(out.stdout)
        if out.returncode != 0:
            fail(f"proden_bench_pipeline exit {out.returncode}: {out.stderr}")
        p = json.load(open(js))
        if p.get("repeat") != 3:
            fail(f"repeat = {p.get('repeat')}")
        s = p["sizes"][0]
        if (s["width"], s["height"]) != (64, 48):
            fail("size")
        for k in ("read_s", "write_s", "write_published_s", "write_piz_s", "compress_later_s",
                  "update_s", "update_piz_s", "peak_rss_bytes"):
            if not (finite(s[k]) and s[k] > 0):
                fail(f"sizes[0].{k} = {s[k]}")
        # The update as published (uncompressed) differs from the PIZ one by the writes alone.
        if abs(s["update_piz_s"] - s["update_s"] - (s["write_piz_s"] - s["write_published_s"])) > 1e-5:
            fail("update_piz_s")
        if s["state_bytes_per_pixel"] != s["layout_bytes_per_pixel"] or s["state_bytes_per_pixel"] < 120:
            fail("bytes per pixel")
        for k in ("denoise", "mixer", "ttest", "wall"):
            if not (s["analytic_1"][k] > 0 and s["analytic_n"][k] > 0):
                fail(f"stage {k}")
        r = p["ratios"]
        for k in ("update_over_cycles_spp", "sure_over_denoise_analytic",
                  "jacobian_over_denoise_paired", "threads_speedup"):
            if not finite(r[k]):
                fail(f"ratio {k} = {r[k]}")
        if p["huge_pages"] not in ("advised", "always", "off", "sanitizer"):
            fail(f"huge_pages = {p['huge_pages']}")
        if not p["sgemm"]["gflops_1"] > 0:
            fail("sgemm")
        if p["frame"] != []:
            fail(f"synthetic frame listed as {p['frame']}")
    with tempfile.TemporaryDirectory() as d:  # a real frame (--pass), as bench/update_cost.sh runs it
        js = os.path.join(d, "update.json")
        passes = [os.path.join(samples, "renders", "cornell", f"pass_0{k}.exr") for k in range(3)]
        args = [os.path.join(bindir, "proden_bench_pipeline"), "--no-mc", "--threads", "2",
                "--cycles-spp-seconds", "1", "--json", js, "--tmp", d]
        for f in passes:
            args += ["--pass", f]
        out = subprocess.run(args, capture_output=True, text=True)
        print(out.stdout)
        if out.returncode != 0:
            fail(f"proden_bench_pipeline --pass exit {out.returncode}: {out.stderr}")
        p = json.load(open(js))
        if p["frame"] != passes or len(p["sizes"]) != 1:
            fail(f"real frame {p['frame']}, {len(p['sizes'])} sizes")
        s = p["sizes"][0]
        if (s["width"], s["height"]) != (128, 128) or not s["exr_mb"] > 0:
            fail(f"real frame size {s['width']}x{s['height']}, {s['exr_mb']} MB")
        for k in ("read_s", "write_published_s", "write_piz_s", "compress_later_s", "update_s"):
            if not (finite(s[k]) and s[k] > 0):
                fail(f"real frame sizes[0].{k} = {s[k]}")
        if not finite(p["ratios"]["update_over_cycles_spp"]):
            fail("real frame update ratio")
    with tempfile.TemporaryDirectory() as d:
        js = os.path.join(d, "network.json")
        out = subprocess.run([os.path.join(bindir, "proden_bench_network"), "--size", "40x24",
                              "--tile", "16", "--width", "8", "--threads", "2", "--json", js],
                             capture_output=True, text=True)
        print(out.stdout)
        if out.returncode != 0:
            fail(f"proden_bench_network exit {out.returncode}: {out.stderr}")
        runs = json.load(open(js))["runs"]
        if [r["threads"] for r in runs] != [1, 2] or any(r["width"] != 8 for r in runs):
            fail(f"network runs {runs}")
        for r in runs:
            for k in ("seconds", "mp_per_s", "gflops_executed", "sgemm_gflops", "ratio"):
                if not (finite(r[k]) and r[k] > 0):
                    fail(f"network {k} = {r[k]}")
            if not r["gflops_executed"] >= r["gflops_useful"]:
                fail("executed flops must include the halos")
    with tempfile.TemporaryDirectory() as d:
        js = os.path.join(d, "nfor.json")
        out = subprocess.run([os.path.join(bindir, "proden_bench_nfor"), "--width", "64",
                              "--height", "48", "--threads", "2", "--isa", "baseline",
                              "--json", js], capture_output=True, text=True)
        print(out.stdout)
        if out.returncode != 0:
            fail(f"proden_bench_nfor exit {out.returncode}: {out.stderr}")
        rows = json.load(open(js))["rows"]
        if [r["denoiser"].split()[0] for r in rows] != ["nlmeans", "nfor"]:
            fail(f"nfor rows {rows}")
        for r in rows:
            if not (finite(r["us_per_pixel"]) and r["us_per_pixel"] > 0):
                fail(f"nfor speed {r}")
        if not rows[1]["stages"]["first_pass"] > 0:
            fail("nfor stages")
    out = subprocess.run([os.path.join(bindir, "proden_nfor_eval"), "--scene",
                          os.path.join(samples, "renders", "cornell"), "--json", "--no-mc"],
                         capture_output=True, text=True)
    if out.returncode != 0:
        fail(f"proden_nfor_eval exit {out.returncode}: {out.stderr}")
    rows = [json.loads(l) for l in out.stdout.splitlines() if l.strip()]
    if len(rows) != 1 or rows[0]["mode"] != "nfor":
        fail(f"nfor eval rows {rows}")
    for k in ("render", "nlmeans", "nfor"):
        if not (finite(rows[0][k]["relmse"]) and rows[0][k]["relmse"] > 0):
            fail(f"nfor eval {k}")
    if set(rows[0]["estimates"]) != {"hat", "cv"}:
        fail(f"nfor eval estimates {rows[0]['estimates']}")
    print(json.dumps(rows[0]))
    out = subprocess.run([os.path.join(bindir, "proden_eval_levels"), "--scene",
                          os.path.join(samples, "renders", "cornell"), "--json"],
                         capture_output=True, text=True)
    if out.returncode != 0:
        fail(f"proden_eval_levels exit {out.returncode}: {out.stderr}")
    rows = [json.loads(l) for l in out.stdout.splitlines() if l.strip()]
    if len(rows) != 1:
        fail(f"{len(rows)} rows")
    row = rows[0]
    print(json.dumps(row))
    for k in ("render", "denoised", "result"):
        for m in ("rmse", "relmse", "smape", "mse_corrected"):
            if not finite(row[k][m]):
                fail(f"{k}.{m}")
    for k in ("estimated_mse_render", "estimated_mse_denoised", "estimated_mse_result"):
        if not (finite(row[k]) and row[k] > 0):
            fail(k)
    for k in ("read_accumulate", "pipeline_wall", "denoise_only_wall", "update"):
        if not (finite(row["seconds"][k]) and row["seconds"][k] > 0):
            fail(f"seconds.{k}")
    # On the bundled cornell passes (8 x 4 spp) the pipeline lowers relMSE several-fold.
    if not row["result"]["relmse"] < row["render"]["relmse"]:
        fail("result relMSE not below the render's")
    print("check_harness: ok")


if __name__ == "__main__":
    main()
