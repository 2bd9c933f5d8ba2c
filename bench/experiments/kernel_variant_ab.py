"""The kernel as committed against a variant of it, side by side in one process.

Some variants of the kernel change its speed and its first compilation but not its
arithmetic, so the two fly the same bits. This script copies the package twice into a
temporary directory, under two names of their own (each with its own numba cache, so each
compiles once). It applies the variant's edit to the second copy and times both with
``bench/bench_kernel.py``'s ``measure``: one period of converging-N per ``advance`` call, the
two kernels' calls alternating, medians over rounds and the median of the per-round ratios.
The first calls of each copy (its compilation) are timed apart.

Variants:

- ``trig-inline``: the kernel's own atan2 and sincos (``atc_nf_env.trig``) inlined at
  numba's level (``inline="always"``) everywhere, the general scalar path too;
- ``commands-call``: the law's commands (``kernel._commands``) compiled as a function of
  their own, called, instead of inlined at numba's level into the world loop;
- ``no-ordinary-step``: every step of the scalar path flown by its general code, none by
  the one-world runs of ordinary steps (``kernel._ordinary_run``): the kernel before the
  one-world ordinary step;
- ``lane-trig-call``: the lane step's atan2 and sincos loops call the functions compiled
  on their own (``trig.poly_atan2``, ``trig.poly_sincos``) instead of their inlined forms:
  the kernel before it inlined them there (``trig-inline`` inlines them everywhere).

Run: python bench/experiments/kernel_variant_ab.py --variant trig-inline [--rounds 11]
"""

from __future__ import annotations

import argparse
import importlib
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
NJIT = '@njit(cache=True, fastmath=FAST_MATH_FLAGS, error_model="numpy")'
#: Each variant's edits: (file of the package, text, its replacement, times the text occurs).
VARIANTS = {
    "trig-inline": [("trig.py", f"{NJIT}\ndef poly_", NJIT[:-1] + ', inline="always")\ndef poly_', 2)],
    "commands-call": [("kernel.py", NJIT[:-1] + ', inline="always")\ndef _commands(',
                       NJIT[:-1] + ", **NO_REFERENCE_COUNTS)\ndef _commands(", 1)],
    "no-ordinary-step": [("kernel.py", "ordinary_law = ordinary_steps and params[nf.P_K] == 2.0",
                          "ordinary_law = False", 1)],
    "lane-trig-call": [
        ("kernel.py", "theta[b] = trig.poly_atan2_inlined(theta[b]", "theta[b] = trig.poly_atan2(theta[b]", 1),
        ("kernel.py", "sin_h[b], cos_h[b] = trig.poly_sincos_inlined(heading[b])",
         "sin_h[b], cos_h[b] = trig.poly_sincos(heading[b])", 1),
    ],
}


def copy_package(target: Path, name: str) -> None:
    """The package ``atc_nf_env`` under ``target/name``, its imports pointed at that name."""
    shutil.copytree(ROOT / "atc_nf_env", target / name, ignore=shutil.ignore_patterns("__pycache__"))
    for path in (target / name).rglob("*.py"):
        path.write_text(re.sub(r"\batc_nf_env\b", name, path.read_text()))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variant", choices=sorted(VARIANTS), required=True)
    parser.add_argument("--rounds", type=int, default=11)
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error("--rounds must be >= 1")
    with tempfile.TemporaryDirectory() as tmp:
        target = Path(tmp)
        copy_package(target, "kernel_as_committed")
        copy_package(target, "kernel_variant")
        for file_name, old, new, count in VARIANTS[args.variant]:
            source = target / "kernel_variant" / file_name
            text = source.read_text()
            if text.count(old) != count:
                raise SystemExit(f"the variant's edit no longer applies to {file_name}: update VARIANTS")
            source.write_text(text.replace(old, new))
        sys.path[:0] = [str(target), str(ROOT / "bench")]
        import bench_kernel

        kernels, compile_s = {}, {}
        for label, package in (("committed", "kernel_as_committed"), ("variant", "kernel_variant")):
            t0 = time.perf_counter()
            kernels[label] = importlib.import_module(f"{package}.kernel")
            for n_worlds in (1, 32):
                case = bench_kernel.Case(kernels[label], n_worlds, 4)
                case.seconds(case.start.copy())
            compile_s[label] = time.perf_counter() - t0
        print(f"variant {args.variant}; first calls (compilation): committed {compile_s['committed']:.1f} s, "
              f"variant {compile_s['variant']:.1f} s", flush=True)
        bench_kernel.KERNELS.clear()
        bench_kernel.KERNELS["frozen"], bench_kernel.KERNELS["current"] = kernels["committed"], kernels["variant"]
        for n_worlds, n_aircraft in ((1000, 4), (1000, 6), (1, 4), (1, 6)):
            r = bench_kernel.measure(n_worlds, n_aircraft, args.rounds)
            print(f"B = {n_worlds}, N = {n_aircraft}: committed {r['frozen'] / 1e6:.2f} M, variant "
                  f"{r['current'] / 1e6:.2f} M aircraft-steps/s, variant / committed {r['ratio']:.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
