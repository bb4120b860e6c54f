"""This CPU's peak float32 rate: fused multiply-adds and nothing else, on every thread asked for.

    .venv/bin/python benchmarks/fma_peak.py [--threads 2]

The ceiling any matrix-product kernel works under: bench_learner.py prints each library's
256x256x256 product as a share of it (issue 48, item 2: products at the CPU's best). A short C
loop (below) runs 12 independent chains of vector FMAs per thread, enough to keep every FMA pipe
busy through the instruction's latency, once with 256-bit vectors and, where the CPU has
AVX-512, once with 512-bit ones; the best of 3 runs of each counts. It is compiled here with the
C compiler inductor uses (CC, else cc) and -march=native, into a temporary directory; without a
compiler the peak is not measured (None).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
from pathlib import Path
from typing import Optional

# 12 chains of vector FMAs per OpenMP thread; their start values come from argv, so that the
# compiler can neither fold them into one chain nor compute them ahead. Prints GFLOP/s.
SOURCE = r"""
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
typedef float vec __attribute__((vector_size(WIDTH)));
#define LANES (WIDTH / 4)
static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + 1e-9 * t.tv_nsec; }
int main(int argc, char **argv) {
    int threads = atoi(argv[1]);
    long steps = atol(argv[2]);
    float seed = (float)atof(argv[3]);
    float sink = 0;
    double start = now();
    #pragma omp parallel num_threads(threads) reduction(+:sink)
    {
        vec a[12], b, c;
        for (int j = 0; j < LANES; j++) { b[j] = 0.999999f; c[j] = 1e-7f; }
        for (int i = 0; i < 12; i++) for (int j = 0; j < LANES; j++) a[i][j] = seed + 0.01f * i + 0.001f * j;
        for (long s = 0; s < steps; s++) {
            #pragma GCC unroll 12
            for (int i = 0; i < 12; i++) a[i] = a[i] * b + c;
        }
        for (int i = 0; i < 12; i++) for (int j = 0; j < LANES; j++) sink += a[i][j];
    }
    double seconds = now() - start;
    printf("%f %f\n", 2.0 * 12 * LANES * steps * threads / seconds / 1e9, sink);
    return 0;
}
"""

STEPS = 200_000_000  # per thread: about 0.3 s at 256 bits and a few GHz


def widths() -> list[int]:
    """The vector widths to try, in bytes: 32 (AVX2), and 64 where the CPU has AVX-512."""
    try:
        flags = Path('/proc/cpuinfo').read_text()
    except OSError:
        flags = ''
    return [32, 64] if ' avx512f' in flags else [32]


def peak_gflops(threads: int, runs: int = 3) -> Optional[float]:
    """The best GFLOP/s of the FMA loop at ``threads`` threads, or None where it cannot be built
    or run (no C compiler, no OpenMP)."""
    compiler = os.environ.get('CC', 'cc')
    best = 0.0
    with tempfile.TemporaryDirectory(prefix='fma_peak') as tmp:
        source = Path(tmp) / 'fma.c'
        source.write_text(SOURCE)
        for width in widths():
            binary = Path(tmp) / f'fma{width}'
            command = [compiler, '-O2', '-march=native', '-ffp-contract=fast', '-fopenmp']
            try:
                subprocess.run(
                    [*command, f'-DWIDTH={width}', str(source), '-o', str(binary)],
                    check=True,
                    capture_output=True,
                    timeout=60,
                )
            except (OSError, subprocess.SubprocessError):
                return None
            for run in range(runs):
                try:
                    out = subprocess.run(
                        [str(binary), str(threads), str(STEPS), f'1.{run}'],
                        capture_output=True,
                        text=True,
                        timeout=60,
                        check=True,
                    )
                    best = max(best, float(out.stdout.split()[0]))
                except (OSError, subprocess.SubprocessError, ValueError, IndexError):
                    return None
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--threads', type=int, default=2)
    args = parser.parse_args()
    peak = peak_gflops(args.threads)
    figure = 'not measured (no C compiler, or the loop would not run)' if peak is None else f'{peak:.0f} GFLOP/s'
    print(f'FMA peak at {args.threads} thread{"s" if args.threads != 1 else ""}: {figure}')


if __name__ == '__main__':
    main()
