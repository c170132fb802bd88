"""Profiles, calibration, simulation and denoising through the Python package."""

import threading

import numpy as np
import pytest

import emccd


def test_default_profile_numbers(profile, tmp_path):
    assert (profile.width, profile.height) == (512, 512)
    assert profile.em_gain == 300 and profile.slope == pytest.approx(20.14)
    assert 100 < profile.bias_dn < 300 and 0 < profile.read_noise_dn < 10
    assert len(profile.fingerprint) == 16 and "512×512" in repr(profile)
    profile.save(tmp_path / "p")
    again = emccd.load_profile(tmp_path / "p")
    assert again.fingerprint == profile.fingerprint
    small = profile.crop(10, 20, 64, 48)
    assert (small.width, small.height) == (64, 48)
    with pytest.raises(emccd.EmccdError, match="loading profile"):
        emccd.load_profile(tmp_path)


@pytest.fixture(scope="module")
def pair(scene, profile):
    """Frames of the scene at a mean of 4 photoelectrons per pixel, and the truth."""
    raw, truth = emccd.simulate_pairs(scene, profile=profile, mean_electrons=4.0, exposure_s=0.01, frames=3, seed=5)
    return raw, truth, profile.crop(0, 0, scene.shape[1], scene.shape[0])


def test_simulated_light_level_and_truth(pair, profile):
    raw, truth, _ = pair
    assert raw.shape == (3, 96, 128) and truth.shape == (96, 128)
    # the truth is K·QE·photons: its mean is 4 photoelectrons at K = slope/2 DN each
    assert truth.mean() == pytest.approx(4.0 * profile.slope / 2, rel=1e-4)
    assert np.all(raw == np.round(raw))  # the ADC's integers


@pytest.mark.parametrize("method", ["ivst", "net"])
def test_denoising_raises_psnr(pair, method):
    raw, truth, prof = pair
    before = emccd.psnr(emccd.denoise(raw[0], prof, method="none", exposure_s=0.01), truth)
    if method == "net":
        # the bundled network was trained through the full-sensor profile, not this sub-array's
        with pytest.warns(UserWarning, match="trained for profile"):
            out = emccd.denoise(raw[0], prof, method=method, exposure_s=0.01)
    else:
        out = emccd.denoise(raw[0], prof, method=method, exposure_s=0.01)
    assert out.shape == truth.shape and out.dtype == np.float32
    after = emccd.psnr(out, truth)
    # 4 e⁻ per pixel: the measured gain of either method on such scenes is 10 dB and more
    assert after > before + 6, (before, after)
    assert emccd.ssim(out, truth) > emccd.ssim(emccd.denoise(raw[0], prof, method="none", exposure_s=0.01), truth)


def test_default_request_is_the_cli_default(pair):
    raw, _, prof = pair
    a = emccd.denoise(raw[:1], prof, exposure_s=0.01)
    b = emccd.denoise(raw[:1], prof, method=emccd.DEFAULT_METHOD, exposure_s=0.01)
    np.testing.assert_array_equal(a, b)


def test_units_dtypes_and_progress(pair):
    raw, _, prof = pair
    calls = []
    dn = emccd.denoise(raw.astype(np.uint16), prof, method="none", exposure_s=0.01, progress=lambda d, t: calls.append((d, t)))
    assert dn.shape == raw.shape and calls == [(1, 3), (2, 3), (3, 3)]
    e = emccd.denoise(raw, prof, method="none", exposure_s=0.01, units="electrons")
    np.testing.assert_allclose(e, dn * 2 / prof.slope, rtol=1e-6)


def test_a_raising_progress_callback_stops_the_work(pair):
    raw, _, prof = pair

    def stop(done, total):
        raise KeyboardInterrupt("stop here")

    with pytest.raises(KeyboardInterrupt, match="stop here"):
        emccd.denoise(raw, prof, method="none", exposure_s=0.01, progress=stop)


def test_denoise_releases_the_interpreter(pair):
    raw, _, prof = pair
    ticks = []
    done = threading.Event()

    def count():
        while not done.is_set():
            ticks.append(1)
            done.wait(0.001)

    t = threading.Thread(target=count)
    t.start()
    emccd.denoise(raw, prof, method="bm3d", exposure_s=0.01)
    done.set()
    t.join()
    assert len(ticks) > 20


def test_bad_requests_raise_clear_errors(pair, profile):
    raw, _, prof = pair
    with pytest.raises(emccd.EmccdError, match="exposure is unknown"):
        emccd.denoise(raw, prof)
    with pytest.raises(emccd.EmccdError, match="profile's sensor is 512×512"):
        emccd.denoise(raw, profile, exposure_s=0.01)
    with pytest.raises(emccd.EmccdError, match="runs no network"):
        emccd.denoise(raw, prof, model="default", method="bm3d", exposure_s=0.01)
    with pytest.raises(emccd.EmccdError, match="the methods are"):
        emccd.denoise(raw, prof, method="wiener", exposure_s=0.01)
    with pytest.raises(emccd.EmccdError, match="model not found"):
        emccd.denoise(raw, prof, model="/nonexistent/model.safetensors", exposure_s=0.01)
    with pytest.raises(emccd.EmccdError, match="positive number of seconds"):
        emccd.denoise(raw, prof, exposure_s=-1)
    with pytest.raises(emccd.EmccdError, match="outside the calibrated range"):
        emccd.denoise(raw, prof, exposure_s=100.0)
    bad = raw[0].copy()
    bad[5, 7] = np.inf
    with pytest.raises(emccd.EmccdError, match=r"frame 1.*pixel \(7, 5\)"):
        emccd.denoise(bad, prof, exposure_s=0.01)
    with pytest.raises(emccd.EmccdError, match="shape"):
        emccd.denoise(raw[None], prof, exposure_s=0.01)
    with pytest.raises(emccd.EmccdError, match="units"):
        emccd.denoise(raw, prof, method="none", exposure_s=0.01, units="photons")


def test_psnr_and_ssim_against_their_formulas():
    rng = np.random.default_rng(9)
    ref = rng.random((40, 50)).astype(np.float32) * 100
    test = ref + rng.normal(0, 3, ref.shape).astype(np.float32)
    mse = np.mean((test.astype(np.float64) - ref) ** 2)
    assert emccd.psnr(test, ref, 100.0) == pytest.approx(10 * np.log10(100.0**2 / mse), abs=1e-4)
    assert emccd.ssim(ref, ref, 100.0) == pytest.approx(1.0, abs=1e-9)
    assert emccd.ssim(test, ref, 100.0) < emccd.ssim(ref + 0.1 * (test - ref), ref, 100.0) < 1
    with pytest.raises(emccd.EmccdError, match="differ in shape"):
        emccd.psnr(ref, ref[:-1])


def test_simulate_pairs_rejects_bad_scenes(profile):
    with pytest.raises(emccd.EmccdError, match="one of photons"):
        emccd.simulate_pairs(np.ones((8, 8)), profile=profile)
    with pytest.raises(emccd.EmccdError, match="sensor"):
        emccd.simulate_pairs(np.ones((600, 8)), profile=profile, photons=10)
    with pytest.raises(emccd.EmccdError, match="2-D"):
        emccd.simulate_pairs(np.ones((2, 8, 8)), profile=profile, photons=10)
    with pytest.raises(emccd.EmccdError, match="brightest"):
        emccd.simulate_pairs(np.zeros((8, 8)), profile=profile, photons=10)


def test_calibrate_recovers_the_virtual_cameras_slope(tmp_path, profile):
    """Flats at six light levels and bias frames at two exposures from the virtual camera on a
    64×64 sub-array, calibrated through the package: the photon-transfer slope comes back."""
    prof = profile.crop(200, 200, 64, 64)
    flat = np.ones((64, 64))
    lines = ['camera = "virtual (python test)"', "em_gain = 300"]
    for i, t in enumerate([0.01, 0.03]):
        raw, truth = emccd.simulate_pairs(flat, profile=prof, photons=0, exposure_s=t, frames=16, seed=10 + i)
        assert not truth.any()  # dark frames: no photo-signal
        emccd.write(tmp_path / f"bias_{i}.tif", raw, dtype=np.uint16, exposure_s=t)
        lines += ["[[bias]]", f'file = "bias_{i}.tif"', f"exposure_s = {t}"]
    for i, level in enumerate([20, 50, 100, 200, 400, 800]):
        raw, _ = emccd.simulate_pairs(flat, profile=prof, photons=level, exposure_s=0.01, frames=16, seed=20 + i)
        emccd.write(tmp_path / f"flat_{i}.tif", raw, dtype=np.uint16, exposure_s=0.01)
        lines += ["[[flat]]", f'file = "flat_{i}.tif"', "exposure_s = 0.01"]
    (tmp_path / "calibration.toml").write_text("\n".join(lines) + "\n")
    seen = []
    got = emccd.calibrate(tmp_path / "calibration.toml", tmp_path / "profile", tmp_path / "report",
                          progress=lambda d, t: seen.append((d, t)))
    # 6 levels × 64² px × 16 frames: the slope's standard error is well under 1 %
    assert got.slope == pytest.approx(profile.slope, rel=0.03)
    assert got.read_noise_dn == pytest.approx(prof.read_noise_dn, rel=0.05)
    assert emccd.load_profile(tmp_path / "profile").fingerprint == got.fingerprint
    assert (tmp_path / "report" / "index.html").is_file()
    assert seen and seen[-1] == (8 * 16, 8 * 16)
    with pytest.raises(emccd.EmccdError):
        emccd.calibrate(tmp_path / "missing.toml", tmp_path / "p2")
    assert not (tmp_path / "p2").exists()
    # The profile just written is not replaced by a second run unless asked.
    before = (tmp_path / "profile" / "profile.toml").read_bytes()
    with pytest.raises(emccd.EmccdError, match="force=True"):
        emccd.calibrate(tmp_path / "calibration.toml", tmp_path / "profile")
    assert (tmp_path / "profile" / "profile.toml").read_bytes() == before
    emccd.calibrate(tmp_path / "calibration.toml", tmp_path / "profile", force=True)


def test_temporal_denoising_of_a_still_stack(pair):
    """Three frames of one still scene: each frame estimated with its neighbours beats the frame
    alone (the same frames through ivst), and a window of 0 is each frame's own estimate: one
    plain BM3D pass at these 2 counts per pixel (iterative BM3D below one count)."""
    raw, truth, prof = pair
    alone = emccd.denoise(raw, prof, method="ivst", exposure_s=0.01)
    together = emccd.denoise(raw, prof, method="temporal", exposure_s=0.01, window=1)
    assert together.shape == raw.shape and together.dtype == np.float32
    gain = np.mean([emccd.psnr(t, truth) - emccd.psnr(a, truth) for t, a in zip(together, alone)])
    assert gain > 0.5, gain
    own = emccd.denoise(raw, prof, method="bm3d", exposure_s=0.01)
    np.testing.assert_array_equal(emccd.denoise(raw, prof, method="temporal", exposure_s=0.01, window=0), own)
    with pytest.raises(emccd.EmccdError, match="--method temporal"):
        emccd.denoise(raw, prof, method="ivst", exposure_s=0.01, window=2)


def test_photon_counting_of_a_faint_stack(scene, profile):
    """300 frames of the scene at 0.05 photo-electrons per pixel: the counted rate's mean is the
    truth's (within 3 %: its standard error is about 0.5 %), the uncertainty is positive and
    about the spread of the error, `per` gives one frame per block, and bad requests raise."""
    raw, truth = emccd.simulate_pairs(scene, profile=profile, mean_electrons=0.05, exposure_s=0.01, frames=300, seed=9)
    prof = profile.crop(0, 0, scene.shape[1], scene.shape[0])
    want = truth / (profile.slope / 2)
    rate, se = emccd.count(raw, prof, exposure_s=0.01)
    assert rate.shape == se.shape == truth.shape
    assert rate.mean() == pytest.approx(want.mean(), rel=0.03)
    err = rate - want
    assert np.all(se > 0) and err.std() == pytest.approx(np.sqrt((se**2).mean()), rel=0.15)
    assert any("threshold" in n for n in emccd.count.last_notes)
    blocks, _ = emccd.count(raw, prof, exposure_s=0.01, per=100, threshold="3sigma")
    assert blocks.shape == (3,) + truth.shape
    analog, _ = emccd.count(raw, prof, exposure_s=0.01, analog=True)
    assert analog.mean() == pytest.approx(want.mean(), rel=0.05)
    with pytest.raises(emccd.EmccdError, match="threshold"):
        emccd.count(raw, prof, exposure_s=0.01, threshold="three")
    with pytest.raises(emccd.EmccdError, match="frames per output"):
        emccd.count(raw, prof, exposure_s=0.01, per=301)


def test_without_a_profile_the_frames_characterize_their_camera(data, profile):
    # A dim fluorescence field (a dark background) on the virtual camera, 8 frames.
    img, _ = emccd.read(data / "clean" / "microscopy" / "fmd-confocal-bpae" / "field1-avg50.png")
    scene = img[0][:128, :128] / img[0].max()
    raw, truth = emccd.simulate_pairs(scene, profile=profile, mean_electrons=1.0, exposure_s=0.01, frames=8, seed=7)
    with pytest.warns(UserWarning, match="camera characterized from the frames"):
        out = emccd.denoise(raw, method="bm3d")
    assert out.shape == raw.shape and np.isfinite(out).all()
    # The mean within 10 % of the truth's (the bias surface's error is a fraction of a DN on a
    # mean of 10 DN; tests/denoise.rs measures the same on the CLI).
    assert out.mean() == pytest.approx(truth.mean(), rel=0.1)
    # The data sheet's spurious charge is subtracted: the output (DN above bias) drops by it,
    # 0.1 e⁻ a frame at s/2 DN each (method "none" is linear, so exactly, to rounding).
    with pytest.warns(UserWarning, match="output keeps them"):
        kept = emccd.denoise(raw, method="none")
    with pytest.warns(UserWarning, match="spurious charge removed"):
        less = emccd.denoise(raw, method="none", exposure_s=0.01, cic=0.05, dark=5.0)
    k = emccd.denoise(raw, method="none", units="electrons", exposure_s=0.01, cic=0.05, dark=5.0)
    assert (kept.mean() - less.mean()) / (less.mean() / k.mean()) == pytest.approx(0.1, rel=1e-4)
    with pytest.raises(emccd.EmccdError, match="exposure is not known"):
        emccd.denoise(raw, method="none", cic=0.05, dark=5.0)
    with pytest.raises(emccd.EmccdError, match="characterized from a recording"):
        emccd.denoise(raw, "default", method="none", exposure_s=0.01, cic=0.05, dark=5.0)
    # The right profile fits; one whose gain and read noise are half the frames' does not.
    right = profile.crop(0, 0, 128, 128)
    emccd.denoise(raw, right, method="none", exposure_s=0.01)
    doubled = (raw - right.bias_dn) * 2 + right.bias_dn
    with pytest.raises(emccd.EmccdError, match="does not fit profile"):
        emccd.denoise(doubled, right, method="none", exposure_s=0.01)
    emccd.denoise(doubled, right, method="none", exposure_s=0.01, force=True)
    # Counting too: the rate holds the spurious charge, and says so.
    rate, _ = emccd.count(raw)
    assert np.isfinite(rate).all()
    assert any("cannot be told from light" in n for n in emccd.count.last_notes)
