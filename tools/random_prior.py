"""A prior of uniform-random actions: the control for prior data of a person's advice.

    .venv/bin/python tools/random_prior.py --env Pendulum-v1 --episode-steps 100 \
        --transitions 1684 --seed 0 --output docs/results/study_pendulum_prior_controlled/random_prior/record.mcap

Writes ``--transitions`` transitions of a policy that draws each action uniformly from the
action space (episodes of ``--episode-steps``, the env reset with ``--seed``, ``--seed + 1``, ...)
as one TransitionBatch marked advised, the form an in-process run's record has: so ``--prior``
(and a study arm's ``learner: {prior: [...]}``) loads them into D and D_advising exactly as it
loads a person's advice. A learner seeded with them starts with as many transitions and updates
from the same step as one seeded with advice; only what the actions are differs
(studies/pendulum_prior_controlled.yaml).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from eqhrl_ros.core import make_env
from eqhrl_ros.core.envs.spec import ActionScaler
from eqhrl_ros.experiments.seed_runs import write_transitions_record


def random_transitions(env, count: int, seed: int) -> list:
    """``count`` transitions of uniform-random actions, as BATCH_COLUMNS (actions in [-1, 1])."""
    rng = np.random.default_rng(seed)
    scaler = ActionScaler(env.action_space.low, env.action_space.high)
    rows: list = [[], [], [], [], []]
    episode = 0
    obs, _ = env.reset(seed=seed)
    while len(rows[2]) < count:
        scaled = rng.uniform(-1.0, 1.0, size=scaler.dim).astype(np.float32)
        # low + (a + 1) (high - low) / 2 is ActionScaler.to_env written another way: the committed
        # control record (pendulum_prior_controlled) was made with this form, and to_env's rounding
        # moves Pendulum's states by 1e-5; kept so that the documented command remakes it bit for bit.
        action = scaler.low + (scaled + 1.0) * 0.5 * (scaler.high - scaler.low)
        next_obs, reward, terminated, truncated, _ = env.step(action)
        for column, value in zip(rows, (obs, scaled, reward, next_obs, float(terminated))):
            column.append(value)
        obs = next_obs
        if terminated or truncated:
            episode += 1
            obs, _ = env.reset(seed=seed + episode)
    return [np.asarray(column, dtype=np.float32) for column in rows]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--env', default='Pendulum-v1')
    parser.add_argument('--episode-steps', type=int, default=None, help="episode length (default: the env's)")
    parser.add_argument('--transitions', type=int, required=True)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--output', type=Path, required=True, help='the .mcap file to write')
    args = parser.parse_args(argv)
    if args.transitions < 1:
        parser.error('--transitions must be at least 1')
    if args.episode_steps is not None and args.episode_steps < 1:
        parser.error('--episode-steps must be at least 1')
    env = make_env(args.env, args.episode_steps)
    columns = random_transitions(env, args.transitions, args.seed)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    write_transitions_record(args.output, columns, env.action_space)
    print(f'{args.output}: {args.transitions} transitions of uniform-random actions on {args.env}')


if __name__ == '__main__':
    main()
