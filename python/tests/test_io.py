"""Reading and writing stacks, checked against the readers users have (tifffile, astropy)."""

import numpy as np
import pytest
import tifffile
from astropy.io import fits

import emccd

INFO_KEYS = {
    "file", "format", "width", "height", "frames", "pixel_type", "exposure_s", "em_gain",
    "temperature_c", "camera_model", "binning", "accumulations", "warnings",
}


def test_real_sif_frames_and_header(data):
    path = data / "emccd-real" / "andor-sif" / "ixon897_avg20.sif"
    frames, meta = emccd.read(path)
    assert frames.shape == (1, 512, 512) and frames.dtype == np.float32
    assert set(meta) == INFO_KEYS
    assert meta["format"] == "sif" and meta["camera_model"] == "DU897_BV"
    assert meta["exposure_s"] == 1.0 and meta["em_gain"] == 1000.0
    assert np.isfinite(frames).all() and frames.std() > 0
    assert emccd.info(path) == meta


def test_truncated_sif_reads_whole_frames_and_warns(data):
    frames, meta = emccd.read(data / "emccd-real" / "andor-sif" / "ixon897_bias_truncated.sif")
    assert frames.shape == (2, 512, 512)
    assert any("truncated" in w for w in meta["warnings"])


def test_lazy_frames_equal_read(tmp_path):
    rng = np.random.default_rng(1)
    stack = rng.integers(0, 60000, size=(5, 20, 31)).astype(np.uint16)
    tifffile.imwrite(tmp_path / "s.tif", stack)
    it = emccd.frames(tmp_path / "s.tif")
    assert len(it) == 5 and it.info["frames"] == 5 and it.info["pixel_type"] == "u16"
    got = np.stack(list(it))
    np.testing.assert_array_equal(got, stack.astype(np.float32))
    np.testing.assert_array_equal(emccd.read(tmp_path / "s.tif")[0], got)


@pytest.mark.parametrize("dtype", [np.float32, np.uint16, np.uint8])
def test_tiff_round_trip_with_tifffile(tmp_path, dtype):
    rng = np.random.default_rng(2)
    stack = (rng.random((3, 17, 23)) * 250).astype(dtype)
    emccd.write(tmp_path / "a.tif", stack, dtype=dtype, exposure_s=0.02, em_gain=300)
    back = tifffile.imread(tmp_path / "a.tif")
    assert back.dtype == np.dtype(dtype)
    np.testing.assert_array_equal(back, stack)
    frames, meta = emccd.read(tmp_path / "a.tif")
    np.testing.assert_array_equal(frames, stack.astype(np.float32))
    assert meta["exposure_s"] == 0.02 and meta["em_gain"] == 300


def test_bigtiff_by_extension(tmp_path):
    stack = np.arange(2 * 8 * 9, dtype=np.float32).reshape(2, 8, 9)
    emccd.write(tmp_path / "a.btf", stack)
    with tifffile.TiffFile(tmp_path / "a.btf") as t:
        assert t.is_bigtiff
        np.testing.assert_array_equal(t.asarray(), stack)


def test_fits_round_trip_with_astropy(tmp_path):
    rng = np.random.default_rng(3)
    stack = rng.normal(500, 30, size=(4, 12, 10)).astype(np.float32)
    emccd.write(tmp_path / "a.fits", stack, exposure_s=0.5)
    np.testing.assert_array_equal(fits.getdata(tmp_path / "a.fits"), stack)
    # and a FITS written by astropy (16-bit unsigned through BZERO) read by emccd
    raw = rng.integers(0, 65535, size=(3, 12, 10)).astype(np.uint16)
    fits.PrimaryHDU(raw).writeto(tmp_path / "b.fits")
    np.testing.assert_array_equal(emccd.read(tmp_path / "b.fits")[0], raw.astype(np.float32))


def test_one_frame_is_written_as_a_stack_of_one(tmp_path):
    emccd.write(tmp_path / "f.tif", np.ones((6, 7)))
    assert tifffile.imread(tmp_path / "f.tif").shape == (6, 7)
    assert emccd.read(tmp_path / "f.tif")[0].shape == (1, 6, 7)


def test_bad_writes_raise_and_leave_the_target_alone(tmp_path):
    target = tmp_path / "keep.tif"
    target.write_bytes(b"precious")
    bad = np.ones((2, 4, 4), dtype=np.float32)
    bad[1, 2, 3] = np.nan
    with pytest.raises(emccd.EmccdError, match=r"non-finite value .* pixel \(3, 2\)"):
        emccd.write(target, bad)
    assert target.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.tif"]
    with pytest.raises(emccd.EmccdError, match="reads it only"):
        emccd.write(tmp_path / "x.sif", np.ones((4, 4)))
    with pytest.raises(emccd.EmccdError, match="must end in"):
        emccd.write(tmp_path / "x.jpg", np.ones((4, 4)))
    with pytest.raises(emccd.EmccdError, match="float32, uint16 or uint8"):
        emccd.write(tmp_path / "x.tif", np.ones((4, 4)), dtype=np.int64)
    with pytest.raises(emccd.EmccdError, match="shape"):
        emccd.write(tmp_path / "x.tif", np.ones((2, 2, 4, 4)))


def test_unreadable_files_raise_the_cli_message(tmp_path, data):
    with pytest.raises(emccd.EmccdError, match="not a TIFF, BigTIFF, Andor SIF, FITS or PNG file"):
        emccd.read(data / "emccd-real" / "andor-sif" / "LICENSE")
    with pytest.raises(emccd.EmccdError, match="No such file"):
        emccd.info(tmp_path / "missing.tif")
    with pytest.raises(emccd.EmccdError):
        emccd.frames(tmp_path)
