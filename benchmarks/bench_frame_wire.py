"""Bytes per transition of a camera's frames on the wire (issue 49, item 4): an actor's
TransitionBatch to the trainer, and the record's, as they are serialized (CDR), against the two
ways a batch could hold them without BatchFrames.

    .venv/bin/python benchmarks/bench_frame_wire.py
    .venv/bin/python benchmarks/bench_frame_wire.py --envs Pendulum-v1 --size 64 --steps 100

For each env, an episode of ``--steps`` random actions seen through its own rendering
(core/envs/camera_envs.py, resized to ``--size`` square, RGB and grey, stacked by ``--stack``) is
packed as one batch (one episode: what the learner records; an actor's batches of 50 cost a
stack more each). Rows, per transition:
- ``ours``: the serialized TransitionBatch (BatchFrames: each frame once, PNG), all its fields;
- ``raw once``: each frame once, uncompressed (what PNG saves over that);
- ``raw stacks``: every transition's stack and next frame, uncompressed (a naive layout).
No target, no exit code: a reading of what the link carries.
"""

from __future__ import annotations

import argparse

import numpy as np
from rclpy.serialization import serialize_message

from eqhrl_ros.core.data.transitions import BatchFrames, TransitionBatch
from eqhrl_ros.core.envs.camera_envs import camera_env
from eqhrl_ros.core.envs.spec import CameraSpec
from eqhrl_ros.nodes.trainer_msgs import batch_msg


def episode_batch(env_id: str, camera: CameraSpec, steps: int, seed: int = 0) -> TransitionBatch:
    env = camera_env(env_id, camera, max_episode_steps=steps)
    env.action_space.seed(seed)
    obs, _ = env.reset(seed=seed)
    stacks, following, states, next_states, actions = [], [], [], [], []
    for _ in range(steps):
        action = env.action_space.sample()
        next_obs, _, terminated, truncated, _ = env.step(action)
        stacks.append(obs['pixels'])
        following.append(next_obs['pixels'][-1])
        states.append(obs['state'])
        next_states.append(next_obs['state'])
        actions.append(np.clip(action / env.action_space.high, -1, 1))
        obs = next_obs
        if terminated or truncated:
            break
    env.close()
    n = len(stacks)
    return TransitionBatch(
        'bench', 0, np.asarray(states, np.float32), np.asarray(actions, np.float32), np.zeros(n, np.float32),
        np.asarray(next_states, np.float32), np.zeros(n, bool), np.zeros(n, bool),
        frames=BatchFrames.of(stacks, following),
    )  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--envs', nargs='+', default=['Pendulum-v1', 'LunarLanderContinuous-v3'])
    parser.add_argument('--size', type=int, default=84)
    parser.add_argument('--stack', type=int, default=3)
    parser.add_argument('--steps', type=int, default=200)
    args = parser.parse_args()
    print('| env | frames | transitions | ours, bytes/transition | raw once | raw stacks | ours / raw stacks |')
    print('|---|---|---|---|---|---|---|')
    for env_id in args.envs:
        for channels in (3, 1):
            camera = CameraSpec(args.size, args.size, channels, args.stack)
            batch = episode_batch(env_id, camera, args.steps)
            frames, n = batch.frames, len(batch)
            space = camera.height * camera.width * camera.channels
            ours = len(
                serialize_message(batch_msg(batch, [-1.0] * batch.actions.shape[1], [1.0] * batch.actions.shape[1]))
            )
            once = len(frames.frames) * space / n
            naive = (camera.stack + 1) * space
            kind = f'{args.size}x{args.size} {"RGB" if channels == 3 else "grey"}, stack {camera.stack}'
            print(
                f'| {env_id} | {kind} | {n} | {ours / n:,.0f} | {once:,.0f} | {naive:,.0f} | {ours / n / naive:.3f} |'
            )
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
