"""Seeds together (core/algorithm/stacked_seeds.py, training.train_stacked) compute what seeds apart compute."""

import numpy as np
import pytest
import torch

from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert, make_env
from eqhrl_ros.core.algorithm.stacked_seeds import StackedSeeds, batchable
from eqhrl_ros.core.runs.in_process import SeedRun, train, train_stacked

# Small networks: an update takes milliseconds. Alone and together differ only in float rounding
# (the same kernels at these sizes: 1e-6 apart after 200 updates here); a rounding difference
# at a ReLU's kink can still send two runs apart later, as it can two CPUs.
SMALL = dict(hidden=(64, 64), batch_size=64, learning_starts=1)


def learner(seed, **settings):
    return EQSACLearner(3, [-2.0], [2.0], LearnerConfig(**{**SMALL, 'seed': seed, **settings}))


def weights(learner):
    tensors = [*learner.actor.parameters(), *learner.critic.parameters(), *learner.critic_target.parameters()]
    return torch.cat([t.detach().reshape(-1) for t in tensors] + [learner.log_alpha.detach().reshape(1)])


def fill(learners_by_seed, advised_every):
    """The same transitions into each seed's learners; seed k's advised every advised_every[k] steps (0: never)."""
    rng = np.random.default_rng(0)
    for step in range(60):
        for seed, group in learners_by_seed.items():
            obs, next_obs = rng.normal(size=3), rng.normal(size=3)
            action, reward = rng.uniform(-1, 1, size=1), float(rng.normal())
            every = advised_every[seed]
            for one in group:
                one.store(obs, action, reward, next_obs, step % 13 == 0, bool(every) and step % every == 0)


@pytest.mark.parametrize('mode,actor_on_advice', [('sac', False), ('eqsac', False), ('qasac', True)])
def test_an_update_together_is_each_seeds_own_update(mode, actor_on_advice):
    # Seed 0 never has advice (no second critic step, as alone), seed 1 a little, seed 2 more.
    # Without handing each seed a gradient in its parameter's layout, fused Adam read the
    # transposed actor gradients wrongly (weights 1e-4 apart after one update).
    groups = {seed: [learner(seed, mode=mode, actor_on_advice=actor_on_advice) for _ in range(2)] for seed in range(3)}
    fill(groups, {0: 0, 1: 9, 2: 4})
    alone = [groups[seed][0] for seed in groups]
    batch = StackedSeeds([groups[seed][1] for seed in groups])
    for _ in range(200):
        for one in alone:
            one.update()
        batch.update()
    batch.release()
    for seed in groups:
        single, together = groups[seed]
        assert together.updates == single.updates == 200
        assert torch.allclose(weights(together), weights(single), rtol=0, atol=1e-5), seed
        # Each seed's own Adam state (step counts include the second critic steps) is its lone one.
        assert (
            together.updater.optimizers['critic'].state_dict()['state'][0]['step']
            == single.updater.optimizers['critic'].state_dict()['state'][0]['step']
        )
        # And its random streams are where the lone run left them.
        assert torch.equal(together.rng['update'].get_state(), single.rng['update'].get_state())
        assert torch.equal(together.rng['replay'].get_state(), single.rng['replay'].get_state())
    steps = [groups[seed][1].updater.optimizers['critic'].state_dict()['state'][0]['step'].item() for seed in groups]
    if mode == 'sac':
        assert steps == [200, 200, 200]
    else:
        assert steps[0] == 200 and steps[1] > 200 and steps[2] > 200


def test_released_learners_own_their_weights_and_save_like_lone_ones():
    learners = [learner(seed) for seed in range(2)]
    fill({0: [learners[0]], 1: [learners[1]]}, {0: 0, 1: 0})
    batch = StackedSeeds(learners)
    batch.update()
    batch.release()
    before = weights(learners[1]).clone()
    with torch.no_grad():
        for param in learners[0].actor.parameters():
            param.add_(1.0)
    assert torch.equal(weights(learners[1]), before)
    state = learners[1].state_dict()
    copy = learner(1)
    copy.load_state_dict(state)
    assert torch.equal(weights(copy), before)


def test_learners_that_differ_beyond_the_seed_are_refused():
    assert batchable([learner(0), learner(1)]) == ''
    assert 'batch_size' in batchable([learner(0), learner(1, batch_size=16)])
    with pytest.raises(ValueError, match='cannot learn together.*gamma'):
        StackedSeeds([learner(0), learner(1, gamma=0.9)])
    with pytest.raises(ValueError, match='proportional'):
        StackedSeeds([learner(0, advice_batch='proportional'), learner(1, advice_batch='proportional')])


@pytest.mark.parametrize('env_id,episodes', [('Pendulum-v1', 3), ('LunarLanderContinuous-v3', 3)])
def test_training_together_gives_each_seed_its_lone_run(env_id, episodes):
    """Whole runs with envs, gates and the expert: the same episodes and advice; on LunarLander
    the seeds' episodes end at different steps, so runs leave the batch at different times."""
    config = dict(mode='eqsac', hidden=(32, 32), batch_size=32, learning_starts=100, advising_budget=2)

    def make(seed):
        env = make_env(env_id, 150)
        one = EQSACLearner(
            env.observation_space.shape[0],
            env.action_space.low,
            env.action_space.high,
            LearnerConfig(seed=seed, **config),
        )
        return env, one

    seeds = (0, 1, 2)
    alone, initial = {}, {}
    for seed in seeds:
        env, one = make(seed)
        initial[seed] = weights(one).clone()
        alone[seed] = (train(env, one, episodes, heuristic_expert(env_id), seed=seed), one)
    together, runs, finished = {seed: [] for seed in seeds}, [], []
    for seed in seeds:
        env, one = make(seed)
        runs.append(
            SeedRun(
                env,
                one,
                heuristic_expert(env_id),
                seed,
                on_episode=together[seed].append,
                on_finished=lambda seed=seed: finished.append(seed),
            )
        )
    train_stacked(runs, episodes)
    assert sorted(finished) == list(seeds)
    assert sum(s.advice_given for summaries, _ in alone.values() for s in summaries) > 0  # advice was had
    for seed, run in zip(seeds, runs):
        summaries, single = alone[seed]
        assert [s.length for s in together[seed]] == [s.length for s in summaries]
        assert [s.advice_given for s in together[seed]] == [s.advice_given for s in summaries]
        assert [s.episode_return for s in together[seed]] == pytest.approx(
            [s.episode_return for s in summaries], rel=1e-4
        )
        assert run.learner.updates == single.updates > 0
        # Not bit for bit: float sums run in another order in the batched products, and over
        # hundreds of Adam steps (each up to lr, whatever the gradient's size) such rounding
        # grows by an amount that differs between CPUs (AVX2, AVX-512). What must hold is that
        # both runs learned the same thing: their difference is small beside how far training
        # moved the weights (a seed given another's data or updates differs by about 100 %).
        moved = (weights(single) - initial[seed]).norm()
        assert (weights(run.learner) - weights(single)).norm() < 0.02 * moved


def test_runs_at_different_steps_are_refused():
    env_a, env_b = make_env('Pendulum-v1', 20), make_env('Pendulum-v1', 20)
    ahead = EQSACLearner(3, env_a.action_space.low, env_a.action_space.high, LearnerConfig(**SMALL, seed=0))
    train(env_a, ahead, 1, seed=0)
    fresh = EQSACLearner(3, env_b.action_space.low, env_b.action_space.high, LearnerConfig(**SMALL, seed=1))
    with pytest.raises(ValueError, match='same step'):
        train_stacked([SeedRun(env_a, ahead), SeedRun(env_b, fresh)], 2)


def test_a_seed_learns_alone_again_after_learning_together():
    """Learning together moves a seed's weights into stacked tensors and release() gives them
    back in tensors of their own: the lone update must then step those, not the stacked ones."""
    groups = {seed: [learner(seed, mode='eqsac') for _ in range(2)] for seed in range(2)}
    fill(groups, {0: 5, 1: 7})
    alone = [groups[seed][0] for seed in groups]
    for one in alone + [groups[seed][1] for seed in groups]:
        one.update()  # each learner's update inputs gathered before any stacking
    batch = StackedSeeds([groups[seed][1] for seed in groups])
    for _ in range(3):
        for one in alone:
            one.update()
        batch.update()
    batch.release()
    for _ in range(3):
        for seed in groups:
            groups[seed][0].update()
            groups[seed][1].update()
    for seed in groups:
        single, together = groups[seed]
        assert together.updates == single.updates == 7
        assert torch.allclose(weights(together), weights(single), rtol=0, atol=1e-5), seed
