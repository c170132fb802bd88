#!/usr/bin/env python3
"""Writes the committed bad-input corpus, tests/corpus/bad/ (issue 12): small damaged files of
every kind emccd reads. `tests/bad_input.rs` runs each through the commands that read it; each
must exit 2 with a message naming the file, and leave no output and no temporary file.

File names say what is wrong; the prefix says what reads it: `frames-` (TIFF/SIF/FITS given to
`denoise` — frame by frame, temporally and into a Zarr store —, `count` and `info`), `manifest-` (`calibrate`), `model-` (`denoise --model`), `profile-`
(a directory given to `denoise --profile`). Standard library only; rerun to regenerate.
"""
import json
import os
import struct
import sys
import zlib

OUT = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "tests", "corpus", "bad")
os.makedirs(OUT, exist_ok=True)


def put(name, data):
    with open(os.path.join(OUT, name), "wb") as f:
        f.write(data)


def tiff(width, height, bits=16, fmt=1, strip_offset=None, strip_bytes=None, data=b""):
    """A little-endian one-page TIFF; the strip follows the IFD unless offsets are forced."""
    entries = []
    ifd_offset = 8
    n = 9
    data_offset = ifd_offset + 2 + 12 * n + 4
    if strip_offset is None:
        strip_offset = data_offset
    if strip_bytes is None:
        strip_bytes = min(width * height * bits // 8, 0xFFFFFFFF)
    for tag, typ, val in [
        (256, 4, width), (257, 4, height), (258, 3, bits), (259, 3, 1), (262, 3, 1),
        (273, 4, strip_offset), (277, 3, 1), (279, 4, strip_bytes), (339, 3, fmt),
    ]:
        entries.append(struct.pack("<HHII", tag, typ, 1, val) if typ == 4 else struct.pack("<HHIHH", tag, typ, 1, val, 0))
    return b"II*\0" + struct.pack("<I", ifd_offset) + struct.pack("<H", n) + b"".join(entries) + struct.pack("<I", 0) + data


def float_stack(width, height, pages):
    """A little-endian multi-page float32 TIFF, each page one Deflate strip (constant frames
    compress to a few hundred bytes); `pages` are lists of (pixel index, value) set on 500.0."""
    out = bytearray(b"II*\0" + struct.pack("<I", 0))
    last_link = 4
    for changes in pages:
        frame = [500.0] * (width * height)
        for i, v in changes:
            frame[i] = v
        strip = zlib.compress(struct.pack(f"<{width * height}f", *frame), 9)
        strip_at = len(out)
        out += strip
        out += b"\0" * (len(out) % 2)
        ifd_at = len(out)
        struct.pack_into("<I", out, last_link, ifd_at)
        entries = [(256, 4, width), (257, 4, height), (258, 3, 32), (259, 3, 8), (262, 3, 1),
                   (273, 4, strip_at), (277, 3, 1), (278, 4, height), (279, 4, len(strip)), (339, 3, 3)]
        out += struct.pack("<H", len(entries))
        for tag, typ, val in entries:
            out += struct.pack("<HHII", tag, typ, 1, val) if typ == 4 else struct.pack("<HHIHH", tag, typ, 1, val, 0)
        last_link = len(out)
        out += struct.pack("<I", 0)
    return bytes(out)


def fits(cards, data=b""):
    h = b"".join(c.ljust(80).encode() for c in cards)
    h += b" " * (-len(h) % 2880)
    return h + data


# Frames
put("frames-not-an-image.tif", b"this is a text file, not a TIFF\n" * 4)
put("frames-truncated-header.tif", b"II*\0\x08\0")
put("frames-huge-dimensions.tif", tiff(4294967295, 4294967295, data=b"\0" * 64))
put("frames-65535-square-float.tif", tiff(65535, 65535, bits=32, fmt=3, data=b"\0" * 64))
put("frames-strip-past-the-end.tif", tiff(512, 512, strip_offset=10_000_000, data=b"\0" * 64))
put("frames-truncated-strip.tif", tiff(512, 512, data=b"\0" * 1000))
put("frames-not-a-sif.sif", b"Andor Technology Multi-Channel File\n")
put("frames-garbage.sif", bytes(range(256)) * 4)
put("frames-not-fits.fits", b"NOT A FITS FILE" * 200)
put("frames-no-end-card.fits", fits(["SIMPLE  =                    T", "BITPIX  =                   16", "NAXIS   =                    2", "NAXIS1  =                  512", "NAXIS2  =                  512"]))
put("frames-huge-naxis.fits", fits(["SIMPLE  =                    T", "BITPIX  =                   16", "NAXIS   =                    2", "NAXIS1  =           2147483647", "NAXIS2  =           2147483647", "END"]))
put("frames-truncated-data.fits", fits(["SIMPLE  =                    T", "BITPIX  =                   16", "NAXIS   =                    2", "NAXIS1  =                  512", "NAXIS2  =                  512", "EXPTIME =                 0.01", "END"], b"\0" * 2880))
put("frames-negative-exposure.fits", fits(["SIMPLE  =                    T", "BITPIX  =                    8", "NAXIS   =                    2", "NAXIS1  =                  512", "NAXIS2  =                  512", "EXPTIME =                 -1.0", "END"], b"\0" * (512 * 512 + (-(512 * 512) % 2880))))
# A movie whose second frame holds a NaN: found only once the frames are read, so every command
# that reads a stack (temporal denoising, Zarr output, counting) must refuse it whole.
put("frames-nan-in-the-second-frame.tif", float_stack(512, 512, [[], [(1000, float("nan"))], []]))

# Calibration manifests
put("manifest-not-toml.toml", b"[[bias]\nfile = \n")
put("manifest-missing-file.toml", b'em_gain = 300.0\n[[bias]]\nfile = "no-such-stack.tif"\nexposure_s = 0.01\n')
put("manifest-negative-exposure.toml", b'em_gain = 300.0\n[[bias]]\nfile = "frames-truncated-strip.tif"\nexposure_s = -0.01\n')
put("manifest-damaged-stack.toml", b'em_gain = 300.0\n[[bias]]\nfile = "frames-truncated-strip.tif"\nexposure_s = 0.01\n')
put("manifest-empty.toml", b"")

# Model files
put("model-not-safetensors.safetensors", b"not a model at all")
put("model-header-past-the-end.safetensors", struct.pack("<Q", 1 << 40) + b"{}")
put("model-no-metadata.safetensors", (lambda h: struct.pack("<Q", len(h)) + h + b"\0" * 4)(b'{"w":{"dtype":"F32","shape":[1],"data_offsets":[0,4]}}'))

def model_meta(meta):
    h = json.dumps({"__metadata__": {"emccd_model": json.dumps(meta)}}).encode()
    h += b" " * (-len(h) % 8)
    return struct.pack("<Q", len(h)) + h
put("model-million-channels.safetensors", model_meta({"arch": "unet", "unet": {"base": 1000000, "levels": 4, "in_channels": 2}, "noise_model": "ours", "ablate": [], "profile_fingerprint": "0", "steps": 0, "recipe": ""}))
put("model-seventy-levels.safetensors", model_meta({"arch": "unet", "unet": {"base": 16, "levels": 70, "in_channels": 2}, "noise_model": "ours", "ablate": [], "profile_fingerprint": "0", "steps": 0, "recipe": ""}))

# Profiles (directories)
os.makedirs(os.path.join(OUT, "profile-garbage"), exist_ok=True)
put(os.path.join("profile-garbage", "profile.toml"), b"format_version = \"x\"\n[[[")
os.makedirs(os.path.join(OUT, "profile-no-maps"), exist_ok=True)
put(os.path.join("profile-no-maps", "profile.toml"), b"format_version = 1\n")
