#!/usr/bin/env python3
"""The yardstick of issue 39: emccd's default U-Net (crates/nn/src/unet.rs: 16 channels, 4
levels, two 3×3 convolutions with leaky ReLU 0.2 per level, 2×2 stride-2 convolutions down, 2×2
stride-2 transposed convolutions up, skip concatenation, a 1×1 output added to input channel 0;
≈ 2.5 M parameters) written in PyTorch, trained with AdamW on random crops so that its crops per
second on the lent GPU can stand beside `emccd train`'s. It is a speed measurement only: the
data are synthetic (a smooth scene plus Poisson-like noise and the noise-level channel), the
loss is Charbonnier as `emccd train`'s, and nothing it writes is a model.

    python3 tools/gpu/torch_unet.py --steps 200 --batch 16 --crop 128 [--cpu] > torch.json

Prints one JSON object: device, parameters, steps, batch, crop, crops_per_s (after the first
20 warm-up steps), the first and last losses, and whether every loss was finite.
"""

import argparse
import json
import math
import time

import torch
import torch.nn as nn


class Block(nn.Module):
    def __init__(self, i, o):
        super().__init__()
        self.c1 = nn.Conv2d(i, o, 3, padding=1)
        self.c2 = nn.Conv2d(o, o, 3, padding=1)
        self.act = nn.LeakyReLU(0.2)

    def forward(self, x):
        return self.act(self.c2(self.act(self.c1(x))))


class UNet(nn.Module):
    def __init__(self, channels=16, levels=4, in_channels=2):
        super().__init__()
        self.enc, self.down, self.up, self.dec = (nn.ModuleList() for _ in range(4))
        ch, inp = channels, in_channels
        for _ in range(levels):
            self.enc.append(Block(inp, ch))
            self.down.append(nn.Conv2d(ch, 2 * ch, 2, stride=2))
            inp, ch = 2 * ch, 2 * ch
        self.bottom = Block(ch, ch)
        for _ in range(levels):
            self.up.append(nn.ConvTranspose2d(ch, ch // 2, 2, stride=2))
            self.dec.append(Block(ch, ch // 2))
            ch //= 2
        self.out = nn.Conv2d(ch, 1, 1)

    def forward(self, x):
        base = x[:, :1]
        skips, h = [], x
        for e, d in zip(self.enc, self.down):
            s = e(h)
            skips.append(s)
            h = d(s)
        h = self.bottom(h)
        for u, d in zip(self.up, self.dec):
            h = d(torch.cat([u(h), skips.pop()], 1))
        return base + self.out(h)


def batch(n, c, device, gen):
    """Noisy crops of smooth random scenes with their noise-level channel, and the scenes."""
    coarse = torch.rand(n, 1, c // 16, c // 16, generator=gen, device=device)
    clean = nn.functional.interpolate(coarse, size=(c, c), mode="bilinear", align_corners=False)
    level = 0.05 + 0.2 * torch.rand(n, 1, 1, 1, generator=gen, device=device)
    noisy = clean + level * torch.randn(n, 1, c, c, generator=gen, device=device) * clean.clamp_min(0.05).sqrt()
    return torch.cat([noisy, level.expand(n, 1, c, c)], 1), clean


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--crop", type=int, default=128)
    ap.add_argument("--cpu", action="store_true", help="run on the CPU (a dry run of the script)")
    a = ap.parse_args()
    device = torch.device("cuda" if torch.cuda.is_available() and not a.cpu else "cpu")
    torch.manual_seed(897)
    gen = torch.Generator(device=device).manual_seed(897)
    net = UNet().to(device)
    opt = torch.optim.AdamW(net.parameters(), lr=2e-4, weight_decay=0.02)
    warm = min(20, a.steps // 2)
    losses, t0 = [], None
    for step in range(a.steps):
        if step == warm:
            if device.type == "cuda":
                torch.cuda.synchronize()
            t0 = time.perf_counter()
        x, y = batch(a.batch, a.crop, device, gen)
        loss = torch.sqrt((net(x) - y) ** 2 + 1e-6).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    if device.type == "cuda":
        torch.cuda.synchronize()
    seconds = time.perf_counter() - t0
    print(json.dumps({
        "device": torch.cuda.get_device_name(0) if device.type == "cuda" else "cpu",
        "parameters": sum(p.numel() for p in net.parameters()),
        "steps": a.steps,
        "batch": a.batch,
        "crop": a.crop,
        "crops_per_s": round((a.steps - warm) * a.batch / seconds, 2),
        "loss_first": losses[0],
        "loss_last": losses[-1],
        "finite": all(math.isfinite(v) for v in losses),
    }))


if __name__ == "__main__":
    main()
