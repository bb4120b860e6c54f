"""Env steps per second with one update per step: our learner vs SBX, Stable-Baselines3 and a plain SAC.

    make bench-learner    # or: .venv/bin/python benchmarks/bench_learner.py [--rounds 8 --round-steps 150]

Same process, same sizes (Table 1: 256x256, batch 256), same thread count, fixed
(cpu_threads.fix: the other contenders' thread pools in this process must not count as a
crowd; a node with torch_threads 0 keeps the same count on a quiet machine). Each
contender first fills its replay memory for --warmup steps without updates (not
timed). Then the contenders take turns, --round-steps env steps each per round,
each step followed by one gradient update, for --rounds rounds: a machine that
speeds up or slows down during the run does so for all of them alike. EQSAC runs
inside its advising budget with the heuristic expert, so it also pays for D(s),
E(s) and the second critic step on the advice batch.

Contenders: SBX (Stable Baselines in JAX: the whole update one XLA program), Stable-Baselines3,
a plain single-file SAC written the CleanRL way (benchmarks/plain_sac.py), ours eager (the
shipped default) and ours with compile_update: true (core/algorithm/compiled_update.py: the
whole update one torch.compile program; compiled before timing, its cost printed).

Prints (issue 48, item 4):
- the table: each contender's steps/s on each env (the median of its rounds), the median of
  its per-round ratios to SBX, and the cores it used (CPU seconds of every thread of the
  process over wall seconds, during its turns);
- the products floor of this machine: one 256x256x256 float32 product by torch (alone, and
  per product in the twin critics' batched pair) and by JAX, each as a share of the CPU's FMA
  peak at the same threads (fma_peak.py: the ceiling of any kernel); each contender's step beside the
  time its update's products alone would take (PRODUCTS, at its library's kernel), and for
  ours compiled the ratio to SBX a step of nothing but products would reach. Where that is
  below a target, the target is impossible with this CPU's kernels and the line says so;
  otherwise a missed target's line gives the step that would meet it, and the share of
  products (floor/step) such a step would have, beside SBX's own share;
- EQSAC compiled over SAC compiled, against the products' ratio, 16 / 25 = 0.64x;
- our eager loops at batch 1, interleaved in the same rounds, whose step time is the part
  that does not grow with the batch (Python, operator dispatch, autograd, Adam);
- the denormal floats our compiled learners' Adam moments hold after the rounds. XLA flushes
  denormals to zero, so SBX holds none; torch keeps them, and CPUs that handle them in microcode
  pay for each operation on them. --flush-denormals runs every contender with them flushed
  (torch.set_flush_denormal, set before any of torch's threads start, so that they inherit it).
Exits with 1 if a target is missed: ours compiled SAC >= 1.5x SBX and EQSAC >= 1.0x SBX on
both envs, and EQSAC compiled >= 0.64x SAC compiled.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import eqhrl_ros  # noqa: F401 - first, as in a user's nodes (eqhrl_ros/__init__.py runs before torch loads)

# isort: split
import numpy as np
import torch
from fma_peak import peak_gflops

from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert, make_env
from eqhrl_ros.core.algorithm import cpu_threads

ENVS = ('Pendulum-v1', 'LunarLanderContinuous-v3')
TARGETS = {'sac': 1.5, 'eqsac': 1.0}  # ours compiled / SBX SAC (issue 48)
MODES = tuple(TARGETS)
# Matrix products of 256x256 by 256x256 in one update (Table 1 sizes, batch 256): each
# hidden-to-hidden layer costs one forward and, in a backward pass, up to two more (weight
# and input gradients); the small first and last layers are left out.
#   SAC:   Eq. 4 target (actor 1, target critics 2) + Eq. 5 (2 critics x 3)
#          + Eq. 6 (actor 3, critics 2 forward and 2 input-gradient)             = 16
#   EQSAC: + Eq. 4 on the advice batch (3) + the second Eq. 5 step (6)           = 25
PRODUCTS = {'sac': 16, 'eqsac': 25}


def cpu_model() -> str:
    """The CPU as /proc/cpuinfo names it, with its family and model (which generation: the
    figures differ between them) and whether it has AVX-512; 'unknown' where it cannot say."""
    try:
        lines = Path('/proc/cpuinfo').read_text().splitlines()
    except OSError:
        return 'unknown'
    info: dict = {}
    for line in lines:
        key, _, value = line.partition(':')
        info.setdefault(key.strip(), value.strip())
    avx512 = 'AVX-512' if 'avx512f' in info.get('flags', '').split() else 'no AVX-512'
    name = info.get('model name', 'unknown')
    return f'{name}, family {info.get("cpu family", "?")} model {info.get("model", "?")}, {avx512}'


def openmp_spin() -> str:
    """GOMP_SPINCOUNT as this process's OpenMP read it: libgomp's default (what a user's nodes get
    since 2026-12-04; before, eqhrl_ros set 1,000), or a value set in the environment."""
    return os.environ.get('GOMP_SPINCOUNT', "libgomp's default")


class OursLoop:
    """Algorithm 1's loop, advanced a given number of env steps at a time."""

    def __init__(self, env_id: str, mode: str, warmup: int, batch_size: int = 256, compiled: bool = False):
        self.env = make_env(env_id)
        config = LearnerConfig(
            mode=mode,
            learning_starts=warmup,
            advising_budget=10**6,
            seed=0,
            batch_size=batch_size,
            compile_update=compiled,
        )
        self.learner = EQSACLearner(
            int(np.prod(self.env.observation_space.shape)),
            self.env.action_space.low,
            self.env.action_space.high,
            config,
        )
        self.expert = heuristic_expert(env_id)
        self.obs, _ = self.env.reset(seed=0)
        self.run(warmup)
        self.compile_s = None
        if compiled:  # the first update starts the compiler; timing starts once it is done
            self.run(1)
            start = time.perf_counter()
            if not self.learner.compiled_update.wait():
                raise RuntimeError(f'compile_update failed: {self.learner.compiled_update.failed}')
            self.compile_s = time.perf_counter() - start

    def run(self, steps: int) -> None:
        learner, env = self.learner, self.env
        for _ in range(steps):
            proposal = learner.propose(self.obs)
            if proposal.decision.fire:
                action, advised = learner.resolve_advice(proposal, self.expert(proposal.request)).action_and_advised()
            else:
                action, advised = proposal.action, False
            next_obs, reward, terminated, truncated, _ = env.step(action)
            learner.step(self.obs, action, reward, next_obs, terminated, truncated, advised)
            self.obs = env.reset()[0] if terminated or truncated else next_obs


class BaselinesLoop:
    """SAC of Stable-Baselines3 or of SBX (same API), learn() continued a given number of steps at a time."""

    def __init__(self, env_id: str, warmup: int, library: str = 'sb3'):
        if library == 'sbx':
            from sbx import SAC
        else:
            from stable_baselines3 import SAC

        self.env = make_env(env_id)
        self.model = SAC(
            'MlpPolicy',
            self.env,
            learning_rate=3e-4,
            buffer_size=500_000,
            learning_starts=warmup,
            batch_size=256,
            train_freq=1,
            gradient_steps=1,
            policy_kwargs={'net_arch': [256, 256]},
            seed=0,
            verbose=0,
            **({} if library == 'sbx' else {'device': 'cpu'}),
        )
        # A logger of our own: without one, each learn() call makes an empty SB3-<time> folder in /tmp.
        from stable_baselines3.common.logger import Logger

        self.model.set_logger(Logger(folder=None, output_formats=[]))
        self.model.learn(total_timesteps=warmup)
        self.model.learn(total_timesteps=1, reset_num_timesteps=False)  # SBX: JAX compiles its update here

    def run(self, steps: int) -> None:
        self.model.learn(total_timesteps=steps, reset_num_timesteps=False)


class PlainLoop:
    """The plain single-file SAC of benchmarks/plain_sac.py (the CleanRL style), on the same env."""

    def __init__(self, env_id: str, warmup: int):
        from plain_sac import PlainSAC

        self.loop = PlainSAC(make_env(env_id), warmup)

    def run(self, steps: int) -> None:
        self.loop.run(steps)


@dataclass
class Timing:
    """One contender's rounds: wall and CPU seconds of each (CPU: every thread of the process)."""

    wall: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)

    def rate(self, steps: int) -> float:
        return steps / statistics.median(self.wall)

    def cores(self) -> float:
        return sum(self.cpu) / sum(self.wall)

    def ratio_to(self, other: Timing) -> float:
        """Median of the per-round speed ratios (other's seconds over ours, round by round)."""
        return statistics.median(o / w for o, w in zip(other.wall, self.wall, strict=True))


def denormals(learner) -> tuple[int, int]:
    """(denormal floats, all floats) in the learner's Adam moments. A ReLU unit that no longer
    fires gets a zero gradient at every step, so its weights' first moments shrink by beta1 a step
    into the denormal range, and stay at its smallest value; XLA (SBX) flushes such values to
    zero, torch keeps them unless told to (--flush-denormals)."""
    tiny, found, total = torch.finfo(torch.float32).tiny, 0, 0
    for optimizer in (learner.updater.optimizers or {}).values():
        for state in optimizer.state.values():
            for name in ('exp_avg', 'exp_avg_sq'):
                moments = state[name]
                found += int(((moments != 0) & (moments.abs() < tiny)).sum())
                total += moments.numel()
    return found, total


def compare(env_id: str, args) -> tuple[dict[str, Timing], dict, dict]:
    """Every contender's rounds, interleaved; the compile seconds of ours compiled; and the
    denormals in its Adam moments after the rounds."""
    contenders: dict = {
        'SBX SAC': BaselinesLoop(env_id, args.warmup, 'sbx'),
        'SB3 SAC': BaselinesLoop(env_id, args.warmup),
        'plain SAC': PlainLoop(env_id, args.warmup),
    }
    for mode in MODES:
        contenders[f'ours {mode}'] = OursLoop(env_id, mode, args.warmup)
    compile_s = {}
    for mode in MODES:
        loop = OursLoop(env_id, mode, args.warmup, compiled=True)
        contenders[f'ours {mode} compiled'] = loop
        compile_s[mode] = loop.compile_s
    # The same eager loops at batch 1, in the same rounds: a step without the work that grows
    # with the batch, measured under the same machine conditions.
    for mode in MODES:
        contenders[f'{mode} b=1'] = OursLoop(env_id, mode, args.warmup, batch_size=1)
    timings = {name: Timing() for name in contenders}
    for _ in range(args.rounds):
        for name, loop in contenders.items():
            wall, cpu = time.perf_counter(), time.process_time()
            loop.run(args.round_steps)
            timings[name].cpu.append(time.process_time() - cpu)
            timings[name].wall.append(time.perf_counter() - wall)
    held = {mode: denormals(contenders[f'ours {mode} compiled'].learner) for mode in MODES}
    return timings, compile_s, held


def best_ms(run, repeats: int = 300) -> float:
    """Milliseconds of one call of run, the best of 5 batches of repeats (hot cache)."""
    for _ in range(30):
        run()
    batches = []
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeats):
            run()
        batches.append((time.perf_counter() - start) / repeats * 1e3)
    return min(batches)


def product_ms(size: int = 256) -> dict[str, float]:
    """Milliseconds of one size^3 float32 product on this CPU, by each library's kernels: torch
    as one product (torch.mm) and as the twin critics' batched pair (torch.bmm, per product),
    and JAX's (jit-compiled jnp.matmul, the kernel SBX gets)."""
    a, b, out = torch.randn(size, size), torch.randn(size, size), torch.empty(size, size)
    pair_a, pair_b, pair_out = torch.randn(2, size, size), torch.randn(2, size, size), torch.empty(2, size, size)
    times = {
        'torch mm': best_ms(lambda: torch.mm(a, b, out=out)),
        'torch bmm': best_ms(lambda: torch.bmm(pair_a, pair_b, out=pair_out)) / 2,
    }
    import jax
    import jax.numpy as jnp

    ja, jb = jnp.asarray(a.numpy()), jnp.asarray(b.numpy())
    matmul = jax.jit(jnp.matmul)
    times['JAX'] = best_ms(lambda: matmul(ja, jb).block_until_ready())
    return times


def gflops(ms: float, size: int = 256) -> float:
    return 2 * size**3 / (ms * 1e-3) / 1e9


CACHE = ''


def inductor_cache_state() -> str:
    """'warm' when inductor's on-disk cache already holds compiled code (a compile then mostly
    loads it), else 'cold'."""
    from torch._inductor.runtime.cache_dir_utils import cache_dir

    path = Path(cache_dir())
    return 'warm' if path.is_dir() and any(path.iterdir()) else 'cold'


# The table's rows, fastest kinds first as the issue lists them; b=1 rows are printed apart.
ROWS = (
    'SBX SAC',
    'ours sac compiled',
    'plain SAC',
    'SB3 SAC',
    'ours sac',
    'ours eqsac compiled',
    'ours eqsac',
)


def floor_ms(name: str, products: dict[str, float]) -> float:
    """An update's matrix products alone, at this CPU's speed for the contender's library."""
    mode = 'eqsac' if 'eqsac' in name else 'sac'
    kernel = products['JAX'] if name.startswith('SBX') else min(products['torch mm'], products['torch bmm'])
    return PRODUCTS[mode] * kernel


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--rounds', type=int, default=8)
    parser.add_argument('--round-steps', type=int, default=150)
    parser.add_argument('--warmup', type=int, default=1000)
    parser.add_argument('--threads', type=int, default=2)
    parser.add_argument('--envs', nargs='+', default=list(ENVS))
    parser.add_argument(
        '--flush-denormals',
        action='store_true',
        help='every contender with denormal floats flushed to zero (FTZ/DAZ), as XLA runs SBX',
    )
    args = parser.parse_args()
    if args.flush_denormals:  # before torch's first parallel region: its OpenMP threads inherit the mode
        torch.set_flush_denormal(True)
    cpu_threads.fix(args.threads)  # fixed: side by side, no contender's threads count as a crowd
    global CACHE
    CACHE = inductor_cache_state()
    print(
        f'torch {torch.__version__}, {args.threads} threads, {os.cpu_count()} CPUs ({cpu_model()}), '
        f'OpenMP spin {openmp_spin()}; per env and contender '
        f'{args.rounds} x {args.round_steps} timed steps, interleaved, after {args.warmup} without updates'
    )
    steps = args.round_steps
    # The ceiling of any product kernel on this CPU, measured before the rounds and after them: the
    # best of both, since one measurement can lose a core to something else for its half second
    # (2026-12-06: 117 GFLOP/s after the rounds, 229-232 alone).
    before = peak_gflops(args.threads)
    results = {env_id: compare(env_id, args) for env_id in args.envs}
    products = product_ms()
    peaks = [p for p in (before, peak_gflops(args.threads)) if p is not None]
    peak = max(peaks) if peaks else None
    missed = []

    # The table: medians of the rounds' steps/s, median of the per-round ratios to SBX, cores.
    short = [env_id.split('-')[0].replace('Continuous', '') for env_id in args.envs]
    print()
    print(f'{"contender":22s}' + ''.join(f'{s:>13s}' for s in short) + '  ratio to SBX (per-round median)  cores')
    for name in ROWS:
        cells = ''.join(f'{results[e][0][name].rate(steps):13.1f}' for e in args.envs)
        ratios = ' / '.join(f'{results[e][0][name].ratio_to(results[e][0]["SBX SAC"]):.2f}' for e in args.envs)
        cores = ' / '.join(f'{results[e][0][name].cores():.1f}' for e in args.envs)
        print(f'{name:22s}{cells}  {ratios:32s} {cores}', flush=True)

    # The floor: what an update's products alone cost with each library's kernels on this CPU.
    print()
    print(
        'products, one 256x256x256 float32 product: '
        + ', '.join(f'{k} {ms:.3f} ms ({gflops(ms):.0f} GFLOP/s)' for k, ms in products.items())
    )
    if peak is None:
        print('FMA peak: not measured (no C compiler, or its loop would not run)')
    else:
        shares = ', '.join(f'{k} {gflops(ms) / peak:.0%}' for k, ms in products.items())
        print(f'FMA peak at {args.threads} threads (fma_peak.py): {peak:.0f} GFLOP/s; each product at {shares} of it')
    print(f'{"contender":22s} {"env":26s} {"step ms":>8s} {"floor ms":>9s} {"floor/step":>10s}  target')
    for env_id in args.envs:
        timings, compile_s, held = results[env_id]
        sbx_ms = 1e3 / timings['SBX SAC'].rate(steps)
        for name in ROWS:
            step_ms, floor = 1e3 / timings[name].rate(steps), floor_ms(name, products)
            verdict = ''
            if name.endswith('compiled'):
                mode = name.split()[1]
                target, ratio = TARGETS[mode], timings[name].ratio_to(timings['SBX SAC'])
                # The best this contender could do here: a step of nothing but its products.
                possible = sbx_ms / floor
                verdict = f'>= {target:.1f}x SBX: {ratio:.2f}x' + ('' if ratio >= target else ' MISSED')
                if ratio < target:
                    # What meeting it takes: a step of SBX's over the target, so that share of products.
                    cause = f'; the products alone allow {possible:.2f}x' + (
                        ' (impossible with these kernels)'
                        if possible < target
                        else f'; it needs a step of {sbx_ms / target:.2f} ms (floor/step {target * floor / sbx_ms:.2f})'
                    )
                    verdict += cause
                    missed.append(f'{env_id} {name}: {ratio:.2f}x SBX < {target}x{cause}')
            print(f'{name:22s} {env_id:26s} {step_ms:8.2f} {floor:9.2f} {floor / step_ms:10.2f}  {verdict}')
        # EQSAC at the cost of its products (issue 48): its compiled step at least SAC's, times
        # the products' ratio (PRODUCTS: 16 / 25 = 0.64).
        share = timings['ours eqsac compiled'].ratio_to(timings['ours sac compiled'])
        bound = PRODUCTS['sac'] / PRODUCTS['eqsac']
        print(
            f'{"":22s} {env_id:26s} eqsac compiled / sac compiled: {share:.2f}x (target >= {bound:.2f}x, '
            "the products' ratio)" + ('' if share >= bound else ' MISSED'),
            flush=True,
        )
        if share < bound:
            missed.append(f'{env_id} ours eqsac compiled: {share:.2f}x ours sac compiled < {bound:.2f}x')
        for mode, seconds in compile_s.items():
            print(f'{"":22s} {env_id:26s} compile {mode}: {seconds:.1f} s before timing (inductor cache {CACHE})')
        for mode, (found, total) in held.items():
            print(
                f'{"":22s} {env_id:26s} {mode} compiled, Adam moments after the rounds: {found} of {total} '
                f'denormal (flushed: {"yes" if args.flush_denormals else "no"})'
            )
        # Batch 1: a step without the work that grows with the batch.
        for mode in MODES:
            step_ms, fixed_ms = 1e3 / timings[f'ours {mode}'].rate(steps), 1e3 / timings[f'{mode} b=1'].rate(steps)
            print(
                f'{"":22s} {env_id:26s} step {mode}: {step_ms:.2f} ms at batch 256 = {fixed_ms:.2f} ms at batch 1 '
                f'+ {step_ms - fixed_ms:.2f} ms growing with the batch (eager)',
                flush=True,
            )
    if missed:
        print('targets missed: ' + '; '.join(missed))
        return 1
    print('all targets met')
    return 0


if __name__ == '__main__':
    sys.exit(main())
