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


def fresh_act_draws(count: int, seed: int = 5) -> list:
    streams = RandomStreams(seed, torch.device('cpu'))
    return [streams.noise((1, 2), 'act') for _ in range(count)]


def test_a_draw_made_ahead_is_the_streams_next_draw_and_changes_none_of_its_numbers():
    streams = RandomStreams(5, torch.device('cpu'))
    expected = fresh_act_draws(4)
    ahead = streams.draw_ahead((1, 2), 'act')
    assert streams.draw_ahead((1, 2), 'act') is ahead  # asked again before it is taken: the same draw
    assert streams.drawn_ahead('act') is ahead
    assert torch.equal(ahead, expected[0])
    assert streams.noise((1, 2), 'act') is ahead and streams.drawn_ahead('act') is None
    assert torch.equal(streams.noise((1, 2), 'act'), expected[1])
    # Another draw than the one made ahead (another shape, uniform, the generator itself): as if
    # none had been made, so the stream's numbers stay those of a stream never drawn ahead.
    streams.draw_ahead((1, 3), 'act')
    assert torch.equal(streams.noise((1, 2), 'act'), expected[2])
    streams.draw_ahead((1, 2), 'act')
    assert torch.equal(torch.randn((1, 2), generator=streams['act']), expected[3])
    assert streams.drawn_ahead('act') is None
    uniform = RandomStreams(5, torch.device('cpu'))
    uniform.draw_ahead((1, 2), 'act')
    assert torch.equal(
        uniform.noise((1, 2), 'act', uniform=True),
        RandomStreams(5, torch.device('cpu')).noise((1, 2), 'act', uniform=True),
    )


def test_a_stream_drawn_ahead_is_saved_as_before_the_draw_and_resumes_with_it():
    learner = EQSACLearner(3, [-1.0], [1.0], LearnerConfig(hidden=(8, 8), seed=5))
    reference = RandomStreams(5, torch.device('cpu'))
    expected = [reference.noise((1, 1), 'act'), reference.noise((1, 2), 'act')]
    ahead = learner.streams.draw_ahead((1, 1), 'act')
    saved = learner.state_dict()
    assert torch.equal(saved['rng']['act'], RandomStreams(5, torch.device('cpu'))['act'].get_state())
    resumed = EQSACLearner(3, [-1.0], [1.0], LearnerConfig(hidden=(8, 8), seed=9))
    resumed.streams.draw_ahead((1, 1), 'act')  # its own draw ahead is forgotten by the load
    resumed.load_state_dict(saved)
    assert resumed.streams.drawn_ahead('act') is None
    assert torch.equal(resumed.streams.noise((1, 1), 'act'), ahead)
    assert torch.equal(ahead, expected[0]) and learner.streams.noise((1, 1), 'act') is ahead
    assert torch.equal(learner.streams.noise((1, 2), 'act'), expected[1])
    assert torch.equal(resumed.streams.noise((1, 2), 'act'), expected[1])
