"""Seconds per 512x512 frame of emccd-detect's EMCCDDetect.sim_sub_frame, with the physics of
emccd's default virtual camera: `emccd bench` runs this (embedded at build time) beside its own
synthesis. Usage: python3 emccd_detect_speed.py FRAMES ELECTRONS_PER_PIXEL"""
import sys, time, warnings
warnings.filterwarnings("ignore")
import numpy as np
from emccd_detect.emccd_detect import EMCCDDetect
frames, electrons = int(sys.argv[1]), float(sys.argv[2])
d = EMCCDDetect(em_gain=300.0, full_well_image=78000.0, full_well_serial=105000.0, dark_current=0.001,
                cic=0.005, read_noise=90.0, bias=180.0, qe=0.9, cr_rate=0.0, pixel_pitch=16e-6,
                eperdn=29.8, nbits=16, numel_gain_register=604)
flux = np.full((512, 512), electrons / 0.9 / 0.01)
d.sim_sub_frame(flux, 0.01)
t = time.perf_counter()
for _ in range(frames):
    d.sim_sub_frame(flux, 0.01)
print((time.perf_counter() - t) / frames)
