#!/usr/bin/env bash
# Writes fuzz/seeds/: small valid inputs of every kind (synthetic TIFF and FITS from numpy and
# tifffile, the small Andor SIF files of ../shared/data and the head of a larger one, the
# example manifests, the bundled profile's profile.toml, a tiny trained model). Not committed: ../shared's files keep
# their own licence.
set -euo pipefail
cd "$(dirname "$0")"
S=../../shared/data/emccd-real/andor-sif
mkdir -p seeds/{tiff,sif,fits,manifest,profile,model}
cp "$S/ccd_cli0.sif" "$S/ixon888_spectrum_raman.sif" seeds/sif/
head -c 12000 "$S/ixon897_binned_gain56.sif" >seeds/sif/ixon897_binned_head.sif
chmod u+w seeds/sif/*
python3 - <<'PY'
import numpy as np, tifffile
rng = np.random.default_rng(0)
tifffile.imwrite("seeds/tiff/u16-2frames.tif", rng.integers(0, 1000, (2, 8, 8)).astype(np.uint16), photometric="minisblack", description="exposure_s=0.01\nem_gain=300")
tifffile.imwrite("seeds/tiff/f32.tif", rng.random((8, 8)).astype(np.float32), photometric="minisblack")
tifffile.imwrite("seeds/tiff/u8-big.tif", rng.integers(0, 255, (8, 8)).astype(np.uint8), photometric="minisblack", bigtiff=True)
def fits(cards, data=b""):
    h = b"".join(c.ljust(80).encode() for c in cards)
    h += b" " * (-len(h) % 2880)
    return h + data + b"\0" * (-len(data) % 2880)
card = lambda k, v: f"{k:<8}= {v:>20}"
open("seeds/fits/i16.fits", "wb").write(fits(["SIMPLE  =                    T", card("BITPIX", 16), card("NAXIS", 2), card("NAXIS1", 8), card("NAXIS2", 8), card("BZERO", 32768), card("EXPTIME", 0.01), "END"], np.arange(64, dtype=">i2").tobytes()))
open("seeds/fits/f32-cube.fits", "wb").write(fits(["SIMPLE  =                    T", card("BITPIX", -32), card("NAXIS", 3), card("NAXIS1", 8), card("NAXIS2", 8), card("NAXIS3", 2), "END"], np.arange(128, dtype=">f4").tobytes()))
PY
cp ../examples/*.toml seeds/manifest/
cargo run -q --release --manifest-path ../Cargo.toml -- profile init-default "$PWD/seeds/profile/dflt" --force 2>/dev/null
mv seeds/profile/dflt/profile.toml seeds/profile/default.toml && rm -r seeds/profile/dflt
# A 557-parameter U-Net (2 channels, 1 level), one training step.
F=../../shared/data/clean/microscopy/fmd-confocal-bpae
cargo run -q --release --manifest-path ../Cargo.toml -- train --clean "$F/field1-avg50.png" --val "$F/field2-avg50.png" \
    --steps 1 --batch 1 --crop 32 --channels 2 --levels 1 --checkpoint-every 1 --warmup 1 -o "$PWD/seeds/model/tiny.safetensors" 2>/dev/null
rm -rf seeds/model/tiny.safetensors.ckpt
