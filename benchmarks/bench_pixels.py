"""Learning from pixels at 84x84 (issue 49, item 6): update and acting speed of this package's
camera learner beside a plain DrQ-v2-style SAC written in this file, side by side in one run,
and the memory a transition costs.

    .venv/bin/python benchmarks/bench_pixels.py                 # batch 256 and 128, 3 rounds
    .venv/bin/python benchmarks/bench_pixels.py --batches 128 --rounds 2 --updates 3

Contenders, each with the same work per update (an 84x84 RGB camera stacked by 3, the state of
Pendulum beside it, DrQ-v2's convolutions and SAC-AE's 50-value head, 256x256 actor and twin
critics, DrQ-v2's random shift of every stack, one critic step then the actor and temperature):
- ``ours sac`` / ``ours eqsac``: EQSACLearner with a CameraSpec, eager (the camera's update is
  not compiled yet); EQSAC with D_advising filled, so it takes the second critic step too;
- ``plain``: the same update written plainly, CleanRL-style, over a naive replay memory that
  holds both stacks of every transition.

Interleaved rounds (ours sac, ours eqsac, plain, then again), each timing ``--updates`` updates
after one untimed; the table gives each contender's median ms per update and its speed as a
ratio of the plain loop's, the median of the per-round ratios; acting: ms per step (the
encoder, the actor, and for EQSAC D(s) and E(s)). Memory: bytes per transition of each replay
memory. No target, no exit code: a reading to compare machines and changes by.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np
import torch
from torch import nn

from eqhrl_ros.core import EQSACLearner, LearnerConfig
from eqhrl_ros.core.algorithm import cpu_threads
from eqhrl_ros.core.algorithm.image_encoder import FEATURES, FILTERS, LAYERS, conv_output_size, random_shift
from eqhrl_ros.core.algorithm.memories import SHIFT_PAD
from eqhrl_ros.core.data.frame_replay import frame_bytes
from eqhrl_ros.core.envs.spec import CameraSpec

CAMERA = CameraSpec(84, 84, 3, 3)
STATE, ACTIONS, FILL = 3, 1, 600


def frames(rng, n: int) -> np.ndarray:
    return rng.integers(0, 256, (n, CAMERA.height, CAMERA.width, CAMERA.channels), dtype=np.uint8)


class Ours:
    """This package's learner with a camera, its memories filled with random frames."""

    def __init__(self, mode: str, batch: int):
        config = LearnerConfig(mode=mode, batch_size=batch, learning_starts=1, replay_capacity=10_000, seed=0)
        self.learner = EQSACLearner(STATE, [-2.0], [2.0], config, camera=CAMERA)
        rng, replay = np.random.default_rng(0), self.learner.replay
        replay.start_episode(frames(rng, 1)[0])
        for frame in frames(rng, FILL):
            replay.add(rng.normal(size=STATE), rng.uniform(-1, 1, ACTIONS), 0.0, frame, rng.normal(size=STATE), False)
        if mode == 'eqsac':
            for frame in frames(rng, 64):
                stack = frames(rng, CAMERA.stack)
                self.learner.advice_replay.add_stacked(
                    rng.normal(size=STATE),
                    rng.uniform(-1, 1, ACTIONS),
                    0.0,
                    stack,
                    frame,
                    rng.normal(size=STATE),
                    False,
                )
        self.obs = {'state': np.zeros(STATE, np.float32), 'pixels': frames(rng, CAMERA.stack)}
        self.bytes_per_transition = (
            frame_bytes(replay.capacity, CAMERA.frame_shape) + replay.vectors.saved_bytes_limit()
        ) / replay.capacity

    def update(self) -> None:
        self.learner.update()

    def act(self) -> None:
        self.learner.propose(self.obs)


def encoder() -> nn.Module:
    channels, size = CAMERA.stack * CAMERA.channels, conv_output_size(CAMERA.height)
    layers: list[nn.Module] = [nn.Conv2d(channels, FILTERS, 3, stride=2), nn.ReLU()]
    for _ in range(LAYERS - 1):
        layers += [nn.Conv2d(FILTERS, FILTERS, 3), nn.ReLU()]
    head = [nn.Flatten(), nn.Linear(FILTERS * size * size, FEATURES), nn.LayerNorm(FEATURES), nn.Tanh()]
    return nn.Sequential(*layers, *head)


def mlp(inputs: int, outputs: int, activation=nn.ReLU) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(inputs, 256), activation(), nn.Linear(256, 256), activation(), nn.Linear(256, outputs)
    )


class Plain:
    """DrQ-v2's update shape, SAC's losses, written out in order; naive replay of uint8 stacks."""

    def __init__(self, batch: int):
        torch.manual_seed(0)
        width = STATE + FEATURES
        self.encoder, self.actor = encoder(), mlp(width, 2 * ACTIONS, nn.Tanh)
        self.q1, self.q2 = mlp(width + ACTIONS, 1), mlp(width + ACTIONS, 1)
        self.q1_target, self.q2_target = mlp(width + ACTIONS, 1), mlp(width + ACTIONS, 1)
        self.q1_target.load_state_dict(self.q1.state_dict())
        self.q2_target.load_state_dict(self.q2.state_dict())
        self.log_alpha = torch.zeros((), requires_grad=True)
        critic = [*self.encoder.parameters(), *self.q1.parameters(), *self.q2.parameters()]
        self.critic_opt = torch.optim.Adam(critic, lr=1e-3, foreach=True)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=1e-4, foreach=True)
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=1e-4)
        rng, shape = np.random.default_rng(0), (FILL, CAMERA.stack * CAMERA.channels, CAMERA.height, CAMERA.width)
        self.obs = rng.integers(0, 256, shape, dtype=np.uint8)
        self.next_obs = rng.integers(0, 256, shape, dtype=np.uint8)
        self.state, self.next_state = rng.normal(size=(FILL, STATE)), rng.normal(size=(FILL, STATE))
        self.actions, self.rewards = rng.uniform(-1, 1, (FILL, ACTIONS)), np.zeros((FILL, 1))
        self.batch, self.generator = batch, torch.Generator().manual_seed(0)
        self.bytes_per_transition = 2 * self.obs[0].nbytes + 8 * (2 * STATE + ACTIONS + 2)
        self.one = (torch.from_numpy(self.obs[:1]), torch.zeros(1, STATE))

    def features(self, frames, state):
        return torch.cat([state, self.encoder(frames.float() / 255.0 - 0.5)], 1)

    def policy(self, features):
        mean, raw = self.actor(features).chunk(2, 1)
        log_std = -5.0 + 3.5 * (torch.tanh(raw) + 1)
        eps = torch.randn_like(mean)
        action = torch.tanh(mean + log_std.exp() * eps)
        log_prob = (-0.5 * eps.pow(2) - log_std - 0.9189385 - torch.log(1 - action.pow(2) + 1e-6)).sum(1, keepdim=True)
        return action, log_prob

    def update(self) -> None:
        index = np.random.default_rng().integers(0, FILL, self.batch)
        obs = random_shift(torch.from_numpy(self.obs[index]), SHIFT_PAD, self.generator)
        next_obs = random_shift(torch.from_numpy(self.next_obs[index]), SHIFT_PAD, self.generator)
        state, next_state = (torch.as_tensor(a[index], dtype=torch.float32) for a in (self.state, self.next_state))
        action, reward = (torch.as_tensor(a[index], dtype=torch.float32) for a in (self.actions, self.rewards))
        alpha = self.log_alpha.exp().detach()
        with torch.no_grad():  # Eq. 4: the target from the encoder as it is, no target encoder
            next_features = self.features(next_obs, next_state)
            next_action, next_log_prob = self.policy(next_features)
            both = torch.cat([next_features, next_action], 1)
            target = torch.min(self.q1_target(both), self.q2_target(both)) - alpha * next_log_prob
            y = reward + 0.99 * target
        features = self.features(obs, state)  # the critics' loss trains the encoder
        both = torch.cat([features, action], 1)
        critic_loss = ((self.q1(both) - y) ** 2).mean() + ((self.q2(both) - y) ** 2).mean()
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic_opt.step()
        features = features.detach()  # the actor reads the features detached
        new_action, log_prob = self.policy(features)
        both = torch.cat([features, new_action], 1)
        actor_loss = (alpha * log_prob - torch.min(self.q1(both), self.q2(both))).mean()
        self.actor_opt.zero_grad(set_to_none=True)
        actor_loss.backward()
        self.actor_opt.step()
        alpha_loss = -(self.log_alpha * (log_prob.detach() - ACTIONS)).mean()
        self.alpha_opt.zero_grad(set_to_none=True)
        alpha_loss.backward()
        self.alpha_opt.step()
        with torch.no_grad():
            for net, target_net in ((self.q1, self.q1_target), (self.q2, self.q2_target)):
                torch._foreach_lerp_(list(target_net.parameters()), list(net.parameters()), 0.005)

    @torch.inference_mode()
    def act(self) -> None:
        self.policy(self.features(*self.one))


def timed_ms(run, count: int) -> float:
    run()  # untimed: first calls allocate
    start = time.perf_counter()
    for _ in range(count):
        run()
    return (time.perf_counter() - start) / count * 1e3


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--batches', type=int, nargs='+', default=[256, 128])
    parser.add_argument('--rounds', type=int, default=3)
    parser.add_argument('--updates', type=int, default=4)
    parser.add_argument('--acts', type=int, default=50)
    parser.add_argument('--threads', type=int, default=2)
    args = parser.parse_args()
    cpu_threads.fix(args.threads)  # fixed: side by side, no contender's threads count as a crowd
    print(
        f'torch {torch.__version__}, {args.threads} threads, {os.cpu_count()} CPUs; camera {CAMERA.height}x'
        f'{CAMERA.width}x{CAMERA.channels} stacked by {CAMERA.stack}; {args.rounds} interleaved rounds of '
        f'{args.updates} updates and {args.acts} acting steps per contender'
    )
    for batch in args.batches:
        contenders = {'ours sac': Ours('sac', batch), 'ours eqsac': Ours('eqsac', batch), 'plain': Plain(batch)}
        update = {name: [] for name in contenders}
        act = {name: [] for name in contenders}
        for _ in range(args.rounds):
            for name, contender in contenders.items():
                update[name].append(timed_ms(contender.update, args.updates))
                act[name].append(timed_ms(contender.act, args.acts))
        print(f'\nbatch {batch}')
        print('| contender | ms per update | speed / plain | ms per acting step | replay bytes per transition |')
        print('|---|---|---|---|---|')
        for name, contender in contenders.items():
            ratio = statistics.median(p / o for p, o in zip(update['plain'], update[name], strict=True))
            print(
                f'| {name} | {statistics.median(update[name]):.0f} | {ratio:.2f} | '
                f'{statistics.median(act[name]):.2f} | {contender.bytes_per_transition:,.0f} |'
            )
    frames_100k, naive_100k = frame_bytes(100_000, CAMERA.frame_shape), 100_000 * 2 * CAMERA.stack_size
    print(f'\nD at 100,000 transitions: {frames_100k / 1e9:.2f} GB of frames (naive stacks: {naive_100k / 1e9:.1f} GB)')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
