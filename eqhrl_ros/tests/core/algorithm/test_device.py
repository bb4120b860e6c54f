"""LearnerConfig.device: the learner on cpu or cuda; tests run on the CPU."""

import pytest
import torch

from eqhrl_ros.core import EQSACLearner, LearnerConfig
from eqhrl_ros.core.data.weights import apply_weights, encode_weights


def learner(device: str) -> EQSACLearner:
    config = LearnerConfig(device=device, hidden=(16, 16), batch_size=8, learning_starts=8, queue_length=2)
    return EQSACLearner(3, [-2.0], [2.0], config)


def test_an_unknown_device_is_refused_with_the_choices():
    with pytest.raises(ValueError, match="device.*'cpu', 'cuda'|cpu, cuda"):
        LearnerConfig(device='tpu')


def test_cuda_works_where_there_is_a_gpu_and_is_refused_clearly_where_there_is_none():
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match='torch sees no GPU'):
            learner('cuda')
        return
    gpu, cpu = learner('cuda'), learner('cpu')
    assert next(gpu.actor.parameters()).is_cuda and gpu.log_alpha.is_cuda
    for i in range(20):
        obs = [1.0, 0.0, 0.1 * i]
        for each in (gpu, cpu):
            each.step(obs, each.propose(obs).action, -1.0, obs, False, i == 19)
    assert gpu.updates == cpu.updates > 0
    apply_weights(cpu, encode_weights(gpu))  # weights travel from a GPU trainer to a CPU actor


def test_on_the_cpu_nothing_is_copied_and_the_noise_streams_are_the_learners():
    one, two = learner('cpu'), learner('cpu')
    assert one.device == torch.device('cpu')
    assert torch.equal(one.streams.noise((4, 1), 'update'), two.streams.noise((4, 1), 'update'))
    batch_source = one.replay
    for i in range(10):
        batch_source.add([0.0, 0.0, float(i)], [0.0], 0.0, [0.0, 0.0, 0.0], False)
    batch = batch_source.sample(4, one.rng['replay'])
    assert batch.to(one.device) is batch
