"""Learning from pixels, with and without advice (issue 49, item 6): a weak indication on the
seeds a 2-core CPU affords, not a study.

    .venv/bin/python benchmarks/learn_from_pixels.py --out docs/results/pixels                  # 3 seeds, about 35 min
    .venv/bin/python benchmarks/learn_from_pixels.py --out /tmp/pixels --episodes 5 --seeds 0   # a smoke run

Pendulum-v1 seen through its own rendering (core/envs/camera_envs.py: resized to --size, grey,
stacked by 3), learned by EQSACLearner with that camera, in process, in two settings:
- ``pixels``: the frames alone (the learner's state vector is empty);
- ``pixels+state``: the frames and Pendulum's 3-value state beside them.
Each with ``sac`` (no advice) and ``eqsac`` (the paper's gates; the heuristic expert answers, and
as a person looking at the scene it sees the true state, whatever the learner reads). Runs go
two at a time, one torch thread each. Writes episodes.csv (one row per episode of every run),
pixels.png (the return of each episode, the median over seeds, each seed faint) and table.md
(the last 10 episodes' mean return per run), and prints the table; --report remakes the last two
from episodes.csv.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import statistics
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

SETTINGS = ('pixels', 'pixels+state')
MODES = ('sac', 'eqsac')


def run(setting: str, mode: str, seed: int, episodes: int, size: int) -> list[dict]:
    import numpy as np
    import torch

    torch.set_num_threads(1)
    from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert
    from eqhrl_ros.core.envs.camera_envs import camera_env
    from eqhrl_ros.core.envs.spec import CameraSpec

    camera = CameraSpec(size, size, channels=1, stack=3)
    env = camera_env('Pendulum-v1', camera, max_episode_steps=100)
    with_state = setting == 'pixels+state'
    config = LearnerConfig(
        mode=mode,
        seed=seed,
        batch_size=64,
        learning_starts=500,
        replay_capacity=20_000,
        advising_budget=10,
        compile_update=False,
    )
    learner = EQSACLearner(3 if with_state else 0, env.action_space.low, env.action_space.high, config, camera=camera)
    expert = heuristic_expert('Pendulum-v1')

    def seen(obs):
        return obs if with_state else {'state': np.zeros(0, np.float32), 'pixels': obs['pixels']}

    rows, (obs, _) = [], env.reset(seed=seed)
    while len(rows) < episodes:
        proposal = learner.propose(seen(obs))
        if proposal.decision.fire:
            request = dataclasses.replace(proposal.request, observation=obs['state'])  # the scene, as a person sees it
            action, advised = learner.resolve_advice(proposal, expert(request)).action_and_advised()
        else:
            action, advised = proposal.action, False
        next_obs, reward, terminated, truncated, _ = env.step(action)
        summary = learner.step(seen(obs), action, reward, seen(next_obs), terminated, truncated, advised)
        obs = next_obs
        if summary is not None:
            rows.append(
                {
                    'setting': setting,
                    'mode': mode,
                    'seed': seed,
                    'episode': summary.episode,
                    'return': round(summary.episode_return, 2),
                    'advice_given': summary.advice_given,
                    'updates': learner.updates,
                }
            )
            obs, _ = env.reset()
    env.close()
    return rows


def figure(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from eqhrl_ros.core.algorithm.config import MODE_COLORS, MODE_LABELS

    fig, axes = plt.subplots(1, len(SETTINGS), figsize=(11, 4), sharey=True)
    for ax, setting in zip(axes, SETTINGS):
        for mode in MODES:
            runs = {}
            for r in rows:
                if r['setting'] == setting and r['mode'] == mode:
                    runs.setdefault(r['seed'], []).append(float(r['return']))
            if not runs:
                continue
            length = min(len(v) for v in runs.values())
            for returns in runs.values():
                ax.plot(returns[:length], color=MODE_COLORS[mode], alpha=0.25, linewidth=0.8)
            median = [statistics.median(v[i] for v in runs.values()) for i in range(length)]
            ax.plot(median, color=MODE_COLORS[mode], label=f'{MODE_LABELS[mode]} ({len(runs)} seeds)')
        ax.set_title(f'Pendulum from {setting}')
        ax.set_xlabel('episode')
        ax.legend()
    axes[0].set_ylabel('return')
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def table(rows: list[dict]) -> str:
    """Per run: the mean return of its last 10 episodes, the advice it was given, its updates."""
    lines = [
        '| setting | mode | seed | mean return, last 10 episodes | advice given | updates |',
        '|---|---|---|---|---|---|',
    ]
    runs = sorted(
        {(r['setting'], r['mode'], int(r['seed'])) for r in rows},
        key=lambda k: (SETTINGS.index(k[0]), MODES.index(k[1]), k[2]),
    )
    for setting, mode, seed in runs:
        mine = [r for r in rows if (r['setting'], r['mode'], int(r['seed'])) == (setting, mode, seed)]
        last = statistics.mean(float(r['return']) for r in mine[-10:])
        given = sum(int(r['advice_given']) for r in mine)
        lines.append(f'| {setting} | {mode} | {seed} | {last:.1f} | {given} | {mine[-1]["updates"]} |')
    return '\n'.join(lines) + '\n'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', type=Path, required=True)
    parser.add_argument('--episodes', type=int, default=40)
    parser.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    parser.add_argument('--size', type=int, default=32)
    parser.add_argument('--jobs', type=int, default=2)
    parser.add_argument(
        '--report', action='store_true', help="remake table.md and pixels.png from --out's episodes.csv"
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.report:
        with open(args.out / 'episodes.csv', newline='') as f:
            rows = list(csv.DictReader(f))
    else:
        runs = list(itertools.product(SETTINGS, MODES, args.seeds))
        with ProcessPoolExecutor(args.jobs) as pool:
            futures = [pool.submit(run, s, m, seed, args.episodes, args.size) for s, m, seed in runs]
            rows = [row for future in futures for row in future.result()]
        with open(args.out / 'episodes.csv', 'w', newline='') as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    figure(rows, args.out / 'pixels.png')
    report = table(rows)
    (args.out / 'table.md').write_text(report)
    print(report, end='')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
