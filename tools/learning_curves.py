#!/usr/bin/env python3
"""Learning curves of `emccd train` runs: validation PSNR against wall-clock seconds and against
crops seen, one curve per run, from the lines the trainer logs at every checkpoint
(`step N/M: loss L val PSNR V dB (input I) at T s`).

Usage: python3 tools/learning_curves.py OUT.png LABEL=LOG[:BATCH] ...
  LABEL  the curve's name in the legend (say which lever the run changes)
  LOG    the training log (stderr of `emccd train` without a terminal)
  BATCH  crops per step (default 4), for the crops-seen axis
Also prints each run's points as a Markdown table. Needs matplotlib.
"""

import re
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

LINE = re.compile(
    r"step (\d+)/\d+: loss ([\d.]+) val PSNR ([\d.]+) dB \(input ([\d.]+)\) at (\d+) s"
)


def points(log):
    """(step, loss, val PSNR, input PSNR, seconds) per checkpoint line."""
    out = []
    with open(log) as f:
        for line in f:
            m = LINE.search(line)
            if m:
                s, loss, v, i, t = m.groups()
                out.append((int(s), float(loss), float(v), float(i), int(t)))
    return out


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    out = sys.argv[1]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    every = []
    for spec in sys.argv[2:]:
        label, rest = spec.split("=", 1)
        log, _, batch = rest.partition(":")
        batch = int(batch or 4)
        p = points(log)
        if not p:
            sys.exit(f"{log}: no checkpoint lines with seconds")
        steps = [x[0] for x in p]
        val = [x[2] for x in p]
        every += val
        secs = [x[4] / 60 for x in p]
        a.plot(secs, val, "o-", ms=3, label=label)
        b.plot([s * batch for s in steps], val, "o-", ms=3, label=label)
        print(f"\n{label} ({log}, batch {batch}; input {p[0][3]:.2f} dB)\n")
        print("| step | minutes | loss | val PSNR (dB) |\n|---:|---:|---:|---:|")
        for s, loss, v, _, t in p:
            print(f"| {s} | {t / 60:.1f} | {loss:.5f} | {v:.2f} |")
    a.set_xlabel("wall-clock minutes (2 CPU cores)")
    b.set_xlabel("training crops seen (128²)")
    # The first checkpoints of a slow starter would squash the rest: the axis starts a little
    # below the 10th percentile of all points (earlier points run off the bottom).
    every.sort()
    lo = every[len(every) // 10] - 1.0
    for ax in (a, b):
        ax.set_ylim(bottom=lo)
        ax.set_ylabel("validation PSNR (dB)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Learning curves: held-out Kodak 1–4, 32 crops at 4 light levels (0.3–30 e⁻)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
