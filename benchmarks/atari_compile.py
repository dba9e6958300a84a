"""The paper's Atari CNN with and without ``torch.compile`` (``AtariConfig.compile``),
side by side in one run: milliseconds for the learner's forward + backward of a batch
(16 envs x 5 steps = 80 frame stacks) and for collection's no-grad forward of 16.

    python benchmarks/atari_compile.py                       # CPU, 2 threads
    python benchmarks/atari_compile.py --device cuda --modes default reduce-overhead
    python benchmarks/atari_compile.py --rounds 1 --reps 1 --threads 1     # a smoke run

Rounds alternate between the variants (plain, then each compile mode), after a warm-up
that includes the compilation (its time is printed apart), and the median is reported.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import time

import torch

from torchrl_hybrid.modules import AtariEncoder
from torchrl_hybrid.utils.device import resolve_device


def _sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="auto")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--modes", nargs="+", default=["default"], choices=AtariEncoder.COMPILE_MODES[1:])
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--reps", type=int, default=10, help="calls per round")
    args = p.parse_args()
    for name in ("threads", "rounds", "reps"):
        if getattr(args, name) < 1:
            p.error(f"--{name} must be >= 1, got {getattr(args, name)}")
    try:
        device = resolve_device(args.device)
    except ValueError as err:
        p.error(str(err))
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    plain = AtariEncoder().to(device)
    plain.reuse_features = False  # time the CNN itself
    encoders = {"plain": plain}
    for mode in args.modes:
        encoders[mode] = copy.deepcopy(plain).compile_cnn(mode)
    learn = torch.randint(0, 256, (80, 4, 84, 84), dtype=torch.uint8, device=device)
    collect = learn[:16].clone()

    def fwd_bwd(enc):
        enc(learn).square().mean().backward()

    def fwd(enc):
        with torch.no_grad():
            enc(collect)

    compile_s = {}
    for name, enc in encoders.items():  # warm-up: compiles the forward and backward graphs
        _sync(device)
        t = time.perf_counter()
        for _ in range(3):
            fwd_bwd(enc)
            fwd(enc)
        _sync(device)
        compile_s[name] = time.perf_counter() - t
    times = {(name, part): [] for name in encoders for part in ("fwd_bwd", "fwd")}
    for _ in range(args.rounds):
        for name, enc in encoders.items():
            for part, fn in (("fwd_bwd", fwd_bwd), ("fwd", fwd)):
                _sync(device)
                t = time.perf_counter()
                for _ in range(args.reps):
                    fn(enc)
                _sync(device)
                times[name, part].append((time.perf_counter() - t) / args.reps * 1000)
    print(f"device {device}, {args.threads} CPU threads, torch {torch.__version__}, median of {args.rounds} rounds")
    print(
        f"{'variant':>16} {'fwd+bwd 80 (ms)':>16} {'fwd 16 (ms)':>12} {'warm-up (s)':>12} {'ratio fwd+bwd':>14} "
        f"{'ratio fwd':>10}"
    )
    base = {part: statistics.median(times["plain", part]) for part in ("fwd_bwd", "fwd")}
    for name in encoders:
        m = {part: statistics.median(times[name, part]) for part in ("fwd_bwd", "fwd")}
        print(
            f"{name:>16} {m['fwd_bwd']:16.2f} {m['fwd']:12.2f} {compile_s[name]:12.1f} "
            f"{base['fwd_bwd'] / m['fwd_bwd']:13.2f}x {base['fwd'] / m['fwd']:9.2f}x"
        )
    print("ratio = plain time / this variant's time (above 1: faster than plain)")


if __name__ == "__main__":
    main()
