#!/usr/bin/env python3
"""PyTorch-CPU reference for the training-engine benchmark (crates/neural/benches/engine.rs).

One training step of the dissertation's 8 x 256 ReLU network exactly as the Rust engine runs it:
positional encoding with the identity term (Eq. 5.2, L = 8, tau = 2u - 1), 8 dense layers of
256 with the encoding concatenated back in at layer 4, a softplus output, MSE against targets,
backward, Adam (betas 0.9/0.999, eps 1e-7). Batch 65 536 random points in [0, 1]^3.

Prints one line `pytorch samples_per_s=<median> samples_per_cpu_s=<median> step_ms=<median>
threads=<n> torch=<version>`; samples_per_cpu_s divides the batch by the process CPU time per
step over the threads (the rate if each thread had a core to itself).
Usage: python3 pytorch_step.py [--batch 65536] [--steps 8] [--threads 2]
"""

import argparse
import math
import statistics
import sys
import time


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, default=65536)
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--depth", type=int, default=8)
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--freqs", type=int, default=8)
    args = ap.parse_args()

    try:
        import torch
    except ImportError:
        print("pytorch unavailable: `import torch` failed", file=sys.stderr)
        return 2

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    L, D, H = args.freqs, args.depth, args.width
    enc_dim = 3 * (1 + 2 * L)
    skip = D // 2

    layers = torch.nn.ModuleList()
    for k in range(D):
        fan_in = enc_dim if k == 0 else H
        if k == skip:
            fan_in += enc_dim
        layers.append(torch.nn.Linear(fan_in, H))
    out_layer = torch.nn.Linear(H, 1)
    params = list(layers.parameters()) + list(out_layer.parameters())
    opt = torch.optim.Adam(params, lr=5e-4, betas=(0.9, 0.999), eps=1e-7)
    freqs = (2.0 ** torch.arange(L, dtype=torch.float32)) * math.pi

    def encode(u):
        tau = 2.0 * u - 1.0
        ph = tau[:, :, None] * freqs  # n x 3 x L
        parts = torch.stack([torch.sin(ph), torch.cos(ph)], dim=-1).reshape(u.shape[0], 3, 2 * L)
        return torch.cat([tau[:, :, None], parts], dim=-1).reshape(u.shape[0], enc_dim)

    def net(u):
        g = encode(u)
        h = g
        for k, lin in enumerate(layers):
            if k == skip:
                h = torch.cat([h, g], dim=-1)
            h = torch.relu(lin(h))
        return torch.nn.functional.softplus(out_layer(h)).squeeze(-1)

    x = torch.rand(args.batch, 3)
    y = torch.rand(args.batch)
    times, cpu = [], []
    for i in range(args.warmup + args.steps):
        t0, c0 = time.perf_counter(), time.process_time()
        opt.zero_grad(set_to_none=True)
        loss = torch.mean((net(x) - y) ** 2)
        loss.backward()
        opt.step()
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        if i >= args.warmup:
            times.append(dt)
            cpu.append(dc / torch.get_num_threads())
    med = statistics.median(times)
    med_cpu = statistics.median(cpu)
    print(
        f"pytorch samples_per_s={args.batch / med:.0f} samples_per_cpu_s={args.batch / med_cpu:.0f} "
        f"step_ms={med * 1e3:.1f} "
        f"threads={torch.get_num_threads()} torch={torch.__version__}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
