"""The learner's random streams are independent: of each other, and of every other seed's."""

import torch

from eqhrl_ros.core.algorithm.config import LearnerConfig
from eqhrl_ros.core.algorithm.learner import EQSACLearner
from eqhrl_ros.core.algorithm.streams import STREAMS, RandomStreams, stream_seeds


def test_no_two_seeds_share_a_stream_and_no_stream_is_another_seeds():
    seeds = {}
    for seed in range(200):
        for name, value in stream_seeds(seed).items():
            assert value not in seeds, (seed, name, seeds.get(value))
            seeds[value] = (seed, name)
    assert len(seeds) == 200 * (len(STREAMS) + 1)


def test_seed_ks_streams_draw_other_numbers_than_seed_k_plus_ones():
    # With seed + i, seed 0's update stream was seed 1's action stream, number for number.
    first = {name: torch.randn(8, generator=g) for name, g in RandomStreams(0, torch.device('cpu')).items()}
    second = {name: torch.randn(8, generator=g) for name, g in RandomStreams(1, torch.device('cpu')).items()}
    for a in first.values():
        assert not any(torch.equal(a, b) for b in second.values())


def test_the_same_seed_gives_the_same_learner_and_another_seed_another():
    def weights(seed):
        config = LearnerConfig(hidden=(8, 8), seed=seed)
        return torch.cat([p.detach().flatten() for p in EQSACLearner(3, [-1.0], [1.0], config).actor.parameters()])

    assert torch.equal(weights(3), weights(3)) and not torch.equal(weights(3), weights(4))
