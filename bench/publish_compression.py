#!/usr/bin/python3
"""What each lossless OpenEXR compression costs a published frame: write (+ fsync) and read
seconds with one thread, and the file's size, measured in one run, interleaved, best of --repeat.

The input is a frame as proden publishes it, e.g. `proden denoise --aov --out F.exr PASS...` on
1080p passes (bench/RESULTS.md, "Publishing a frame", has the recipe). The same library writes it
as the daemon does (OpenImageIO over OpenEXR); one thread, so the seconds are CPU-seconds.

    bench/publish_compression.py F.exr [--repeat 3] [--dir DIR]
"""
import argparse
import os
import tempfile
import time

import OpenImageIO as oiio

# protocol/compression.hpp's kFrameCompressions.
COMPRESSIONS = ["piz", "zip", "zips", "rle", "none"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("frame")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dir", help="where the copies are written (default: a temp dir)")
    args = ap.parse_args()
    oiio.attribute("threads", 1)
    oiio.attribute("exr_threads", 1)
    inp = oiio.ImageInput.open(args.frame)
    if not inp:
        raise SystemExit("%s: %s" % (args.frame, oiio.geterror()))
    spec = inp.spec()
    pixels = inp.read_image(oiio.FLOAT)
    inp.close()
    print("%s: %dx%d, %d channels, %.1f MB of floats" %
          (args.frame, spec.width, spec.height, spec.nchannels,
           spec.width * spec.height * spec.nchannels * 4 / 1e6))
    results = {c: [] for c in COMPRESSIONS}
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        path = os.path.join(tmp, "frame.exr")
        for _ in range(args.repeat):
            for c in COMPRESSIONS:
                out_spec = oiio.ImageSpec(spec.width, spec.height, spec.nchannels, oiio.FLOAT)
                out_spec.channelnames = spec.channelnames
                out_spec.attribute("compression", c)
                t = time.perf_counter()
                out = oiio.ImageOutput.create(path)
                if not (out.open(path, out_spec) and out.write_image(pixels) and out.close()):
                    raise SystemExit("%s: %s" % (c, out.geterror()))
                fd = os.open(path, os.O_RDONLY)
                os.fsync(fd)
                os.close(fd)
                write = time.perf_counter() - t
                t = time.perf_counter()
                back = oiio.ImageInput.open(path)
                back.read_image(oiio.FLOAT)
                back.close()
                read = time.perf_counter() - t
                results[c].append((write, read, os.path.getsize(path)))
    zip_write = min(w for w, _, _ in results["zip"])
    print("| compression | write + fsync (s) | read (s) | size (MB) | write / ZIP's |")
    print("|---|---:|---:|---:|---:|")
    for c in COMPRESSIONS:
        w = min(x[0] for x in results[c])
        r = min(x[1] for x in results[c])
        print("| %s | %.2f | %.2f | %.1f | %.2f |" % (c, w, r, results[c][0][2] / 1e6, w / zip_write))


if __name__ == "__main__":
    main()
