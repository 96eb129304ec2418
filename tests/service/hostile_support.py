"""Helpers of the hostile-input service tests (standard library only): hand-made image files
(OpenEXR byte by byte after OpenEXR's "File Layout", with headers no writer would produce; small
PNG and Radiance files) and probes of the daemon process."""
import struct
import zlib

LIVEZ_DEADLINE = 2.0  # seconds; generous: a healthy daemon answers in milliseconds


def proc_status_mib(pid, field):
    """A memory field of /proc/<pid>/status (VmRSS: resident now, VmHWM: peak so far), in MiB."""
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    return 0.0


def vm_hwm_mib(d):
    """Peak resident memory of the daemon process so far (MiB)."""
    return proc_status_mib(d.proc.pid, "VmHWM")


def _attr(name, typ, value, declared=None):
    if isinstance(name, str):
        name = name.encode()
    if isinstance(typ, str):
        typ = typ.encode()
    size = len(value) if declared is None else declared
    return name + b"\0" + typ + b"\0" + struct.pack("<I", size & 0xFFFFFFFF) + value


def string_attr(name, value):
    if isinstance(value, str):
        value = value.encode()
    return _attr(name, "string", value)


def exr(width=4, height=3, channels=(b"B", b"G", b"R"), value=0.25, extra=(), compression=0,
        declared=None, pixels=True, pad=0, tiles=None):
    """An uncompressed scanline (or tiled) EXR of FLOAT channels, all samples `value`.
    declared=(w, h) makes the header claim another size; pixels=False stops after the header;
    pad appends zero bytes (to satisfy size checks of headers that lie)."""
    dw, dh = declared or (width, height)
    chlist = b""
    for c in channels:
        if isinstance(c, str):
            c = c.encode()
        chlist += c + b"\0" + struct.pack("<iBBBBii", 2, 0, 0, 0, 0, 1, 1)
    chlist += b"\0"
    box = struct.pack("<iiii", 0, 0, dw - 1, dh - 1)
    version = 2 | 0x400 | (0x200 if tiles else 0)
    out = b"\x76\x2f\x31\x01" + struct.pack("<I", version)
    out += _attr("channels", "chlist", chlist)
    out += _attr("compression", "compression", bytes([compression]))
    out += _attr("dataWindow", "box2i", box)
    out += _attr("displayWindow", "box2i", box)
    out += _attr("lineOrder", "lineOrder", b"\0")
    out += _attr("pixelAspectRatio", "float", struct.pack("<f", 1.0))
    out += _attr("screenWindowCenter", "v2f", struct.pack("<ff", 0, 0))
    out += _attr("screenWindowWidth", "float", struct.pack("<f", 1.0))
    if tiles:
        out += _attr("tiles", "tiledesc", struct.pack("<IIB", tiles[0], tiles[1], 0))
    for a in extra:
        out += a
    out += b"\0"
    parts = [out]
    if pixels and not tiles:
        line = len(channels) * width * 4
        first = len(out) + 8 * height
        parts.append(b"".join(struct.pack("<Q", first + y * (8 + line)) for y in range(height)))
        row = struct.pack("<f", value) * (width * len(channels))
        parts.extend(struct.pack("<ii", y, line) + row for y in range(height))
    parts.append(b"\0" * pad)
    return b"".join(parts)


def png(width=8, height=8, rgb=(200, 30, 10)):
    """An 8-bit sRGB PNG."""
    raw = b"".join(b"\0" + bytes(rgb) * width for _ in range(height))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def radiance(width=4, height=3):
    """A flat (not run-length encoded) Radiance RGBE file."""
    head = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (height, width)
    return head + bytes([128, 64, 32, 129]) * (width * height)


def write(path, data):
    with open(path, "wb") as f:
        f.write(data)
