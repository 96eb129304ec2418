#!/usr/bin/env python3
"""Runs proden's libFuzzer targets (fuzz/README.md) one at a time and reports them.

  fuzz/run.py smoke    BUILD_DIR [--seconds 20] [--jobs N] each target briefly on the committed
                                                           corpus, N at a time (default: one per
                                                           core); exit 1 on any crash
  fuzz/run.py campaign BUILD_DIR [--seconds N] [--runs N] [--targets a,b]
                                                           each target until N executions or N
                                                           seconds; the sessions are appended to
                                                           BUILD_DIR/fuzz/sessions.json
  fuzz/run.py report   BUILD_DIR [--out bench/results/fuzz.md] [--sessions FILE]...
                                                           the summary of all recorded sessions
                                                           (FILE: another tree's sessions.json)

A session's crashing inputs land in BUILD_DIR/fuzz/artifacts/<target>/ (keep them: copy each into
fuzz/corpus/<target>/ once the bug is fixed, with a regression test in tests/).
"""
import argparse
import concurrent.futures
import datetime
import glob
import json
import os
import re
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

# Per target: libFuzzer options and extra read-only seed directories (repository files).
TARGETS = {
    # Memory bombs are findings: the target's read limits allow 64 MiB per read, so an allocation
    # of 256 MiB (or 1 GiB resident) means a bound was bypassed.
    "pass_reader": {"opts": ["-max_len=16384", "-malloc_limit_mb=256", "-rss_limit_mb=1024"],
                    "dict": "pass_reader.dict"},
    "weights": {"opts": ["-max_len=8192", "-malloc_limit_mb=256", "-rss_limit_mb=1024"],
                "seeds": ["training/weights"]},
    "frame_state": {"opts": ["-max_len=16384", "-malloc_limit_mb=256", "-rss_limit_mb=1024"]},
    "job_config": {"opts": ["-max_len=4096", "-malloc_limit_mb=256", "-rss_limit_mb=1024"],
                   "dict": "json.dict"},
    "http_request": {"opts": ["-max_len=8192", "-malloc_limit_mb=256", "-rss_limit_mb=1024"],
                     "dict": "http_request.dict"},
    "watch_pattern": {"opts": ["-max_len=4096", "-malloc_limit_mb=256", "-rss_limit_mb=1024"],
                      "dict": "watch_pattern.dict"},
}
COMMON = ["-timeout=10", "-print_final_stats=1", "-detect_leaks=1"]


def command(build, target, work, seconds, runs, artifacts):
    t = TARGETS[target]
    cmd = [os.path.join(build, "fuzz", "fuzz_" + target)] + COMMON + t["opts"]
    if "dict" in t:
        cmd.append("-dict=" + os.path.join(HERE, "dict", t["dict"]))
    cmd += ["-max_total_time=%d" % seconds, "-artifact_prefix=" + artifacts + "/"]
    if runs:
        cmd.append("-runs=%d" % runs)
    cmd += [work, os.path.join(HERE, "corpus", target)]
    cmd += [os.path.join(ROOT, s) for s in t.get("seeds", [])]
    return cmd


def parse(log):
    """Executions, exec/s, coverage and features from libFuzzer's output."""
    out = {}
    m = re.search(r"stat::number_of_executed_units:\s*(\d+)", log)
    if m:
        out["executions"] = int(m.group(1))
    m = re.search(r"stat::average_exec_per_sec:\s*(\d+)", log)
    if m:
        out["exec_per_sec"] = int(m.group(1))
    m = re.search(r"stat::peak_rss_mb:\s*(\d+)", log)
    if m:
        out["peak_rss_mb"] = int(m.group(1))
    cov = re.findall(r"cov: (\d+) ft: (\d+) corp: (\d+)/", log)
    if cov:
        out["coverage_edges"], out["features"], out["corpus"] = map(int, cov[-1])
    m = re.search(r"INITED cov: (\d+)", log)
    if m:
        out["coverage_seeds"] = int(m.group(1))
    return out


def run(build, target, seconds, runs, work, artifacts, nice):
    os.makedirs(work, exist_ok=True)
    os.makedirs(artifacts, exist_ok=True)
    cmd = command(build, target, work, seconds, runs, artifacts)
    if nice:
        cmd = ["nice", "-n", "10"] + cmd
    env = dict(os.environ)
    env.setdefault("ASAN_OPTIONS", "abort_on_error=1:detect_leaks=1")
    env.setdefault("UBSAN_OPTIONS", "print_stacktrace=1:halt_on_error=1")
    before = set(os.listdir(artifacts))
    load = os.getloadavg()[0]
    start = datetime.datetime.now(datetime.timezone.utc)
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env,
                       cwd=build, text=True, errors="replace")
    log = p.stdout
    new = sorted(set(os.listdir(artifacts)) - before)
    s = {"target": target, "started": start.isoformat(timespec="seconds"),
         "seconds_asked": seconds, "runs_asked": runs, "exit": p.returncode,
         "crashes": len([a for a in new if not a.startswith("slow-unit")]),
         "artifacts": [os.path.join(artifacts, a) for a in new],
         "command": " ".join(cmd), "load_start": round(load, 1),
         "load_end": round(os.getloadavg()[0], 1)}
    s.update(parse(log))
    m = re.search(r"Done (\d+) runs in (\d+) second", log)
    if m:
        s["wall_seconds"] = int(m.group(2))
    with open(os.path.join(artifacts, "last_%s.log" % target), "w") as f:
        f.write(log)
    if p.returncode != 0:
        tail = "\n".join(log.splitlines()[-60:])
        print(tail, file=sys.stderr)
    return s


def smoke_one(build, target, seconds):
    with tempfile.TemporaryDirectory(prefix="proden-fuzz-smoke-") as work:
        return run(build, target, seconds, 0, work,
                   os.path.join(build, "fuzz", "smoke-artifacts", target), nice=False)


def smoke(args):
    # Each fuzzer is one single-threaded process: one per core runs each at its full rate, so the
    # smoke's wall time is the sum of its targets' seconds divided by the cores.
    jobs = args.jobs or os.cpu_count() or 1
    with concurrent.futures.ThreadPoolExecutor(max_workers=jobs) as pool:
        sessions = list(pool.map(lambda t: smoke_one(args.build, t, args.seconds), args.targets))
    failed = []
    for t, s in zip(args.targets, sessions):
        ok = s["exit"] == 0 and s["crashes"] == 0
        print("fuzz smoke %-14s %s  %s executions, %s exec/s, cov %s" %
              (t, "ok  " if ok else "FAIL", s.get("executions", "?"), s.get("exec_per_sec", "?"),
               s.get("coverage_edges", "?")))
        if not ok:
            failed.append(t)
    if failed:
        print("fuzz smoke: crashes in " + ", ".join(failed), file=sys.stderr)
        return 1
    return 0


def campaign(args):
    log = os.path.join(args.build, "fuzz", "sessions.json")
    sessions = json.load(open(log)) if os.path.exists(log) else []
    status = 0
    for t in args.targets:
        s = run(args.build, t, args.seconds, args.runs,
                os.path.join(args.build, "fuzz", "corpus", t),
                os.path.join(args.build, "fuzz", "artifacts", t), nice=True)
        sessions.append(s)
        with open(log, "w") as f:
            json.dump(sessions, f, indent=1)
        print("fuzz %-14s exit %d: %s executions in %s s (%s exec/s), cov %s, %d crash(es)" %
              (t, s["exit"], s.get("executions", "?"), s.get("wall_seconds", "?"),
               s.get("exec_per_sec", "?"), s.get("coverage_edges", "?"), s["crashes"]),
              flush=True)
        if s["exit"] != 0 or s["crashes"]:
            status = 1
    report(args)
    return status


def report(args):
    log = os.path.join(args.build, "fuzz", "sessions.json")
    sessions = json.load(open(log)) if os.path.exists(log) else []
    # Also the committed records (fuzz/sessions/*.json: campaigns of other trees and machines) and
    # any file given; a session recorded twice counts once.
    extra = sorted(glob.glob(os.path.join(HERE, "sessions", "*.json"))) + args.sessions
    for path in extra:
        sessions += json.load(open(path))
    unique = {}
    for s in sessions:
        unique.setdefault((s["target"], s["started"]), s)
    sessions = sorted(unique.values(), key=lambda s: s["started"])
    bar = 10_000_000
    lines = [
        "## Fuzzing (libFuzzer, ASan + UBSan)",
        "",
        "Generated by `fuzz/run.py report` from the sessions `make fuzz` recorded "
        "(build-fuzz/fuzz/sessions.json, and the records committed in fuzz/sessions/); targets and "
        "properties: fuzz/README.md. "
        "clang 14, `-fsanitize=fuzzer,address,undefined`, under `nice` on a shared 2-core machine "
        "(a campaign runs one fuzzer at a time; campaigns in other build trees, run in parallel, "
        "are merged with `--sessions`). A target's executions are summed over its sessions "
        "(each session resumes from the corpus its tree's previous one grew). Bar: >= 10 M executions "
        "per target, 0 crashes. exec/s depend on the machine's load (the 1-minute load average at "
        "each session's start and end is listed; 2 cores): a projection assumes the same load.",
    ]
    if any(s.get("reconstructed") for s in sessions):
        lines += [
            "",
            "Sessions marked *reconstructed* ran before their build-fuzz/ directory was lost: "
            "their figures are copied from the report written at the time (which kept coverage, "
            "corpus and peak RSS per target only: they are shown on its last such session), and "
            "the corpus they grew was lost, so the sessions after them started again from the "
            "committed corpus.",
        ]
    lines += [
        "",
        "| target | sessions | executions | wall s | exec/s | crashes (open) | coverage (edges) "
        "| corpus | peak RSS MB | bar |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t in TARGETS:
        ss = [s for s in sessions if s["target"] == t]
        if not ss:
            lines.append("| %s | 0 | - | - | - | - | - | - | - | not run |" % t)
            continue
        execs = sum(s.get("executions", 0) for s in ss)
        # A session that stopped on a crash prints no wall time: executions / its exec/s.
        wall = sum(s.get("wall_seconds") or (s.get("executions", 0) / s["exec_per_sec"]
                                             if s.get("exec_per_sec") else 0) for s in ss)
        rate = execs / wall if wall else 0
        crashes = sum(s["crashes"] for s in ss)
        last = ss[-1]
        open_crashes = last["crashes"] + (1 if last["exit"] not in (0,) and not last["crashes"]
                                          else 0)
        if execs >= bar and open_crashes == 0:
            verdict = "met"
        else:
            need = max(bar - execs, 0)
            verdict = "not met: %.2f M short, about %.1f h more at %d exec/s" % (
                need / 1e6, need / rate / 3600 if rate else float("inf"), rate)
            if open_crashes:
                verdict = "crash open"
        lines.append("| %s | %d | %s | %.0f | %.0f | %d (%d) | %s | %s | %s | %s |" % (
            t, len(ss), "{:,}".format(execs), wall, rate, crashes, open_crashes,
            last.get("coverage_edges", "?"), last.get("corpus", "?"),
            max(s.get("peak_rss_mb", 0) for s in ss), verdict))
    lines += ["", "Sessions (latest last):", ""]
    for s in sessions:
        lines.append("- %s `%s`%s: %s executions in %s s, exit %d, %d crash(es), load average %s -> %s"
                     "%s" % (
            s["started"], s["target"], " *reconstructed*" if s.get("reconstructed") else "",
            "{:,}".format(s.get("executions", 0)),
            s.get("wall_seconds", "?"), s["exit"], s["crashes"], s.get("load_start", "?"),
            s.get("load_end", "?"),
            "" if not s["artifacts"] else " -> " + ", ".join(
                os.path.basename(a) for a in s["artifacts"])))
    text = "\n".join(lines) + "\n"
    notes = os.path.join(HERE, "findings.md")
    if os.path.exists(notes):
        text += "\n" + open(notes).read()
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        f.write(text)
    print("wrote " + args.out)
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("mode", choices=["smoke", "campaign", "report"])
    ap.add_argument("build")
    ap.add_argument("--seconds", type=int, default=20)
    ap.add_argument("--runs", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=0, help="smoke: targets at a time (0: cores)")
    ap.add_argument("--targets", default=",".join(TARGETS))
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results", "fuzz.md"))
    ap.add_argument("--sessions", action="append", default=[],
                    help="report: also these sessions.json files (repeatable); the committed "
                    "fuzz/sessions/*.json are always read")
    args = ap.parse_args()
    args.build = os.path.abspath(args.build)
    args.targets = [t for t in args.targets.split(",") if t]
    for t in args.targets:
        if t not in TARGETS:
            ap.error("unknown target " + t)
    return {"smoke": smoke, "campaign": campaign, "report": report}[args.mode](args)


if __name__ == "__main__":
    sys.exit(main())
