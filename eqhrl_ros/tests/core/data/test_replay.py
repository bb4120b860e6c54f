"""The replay memory D: a sampled batch holds whole stored transitions, each column contiguous
(as the update reads it: a compiled program is specialised to its inputs' layout)."""

import numpy as np
import torch

from eqhrl_ros.core.data.replay import BATCH_COLUMNS, ReplayBuffer


def test_a_batch_holds_whole_transitions_each_column_contiguous_and_wraps_the_ring():
    buffer = ReplayBuffer(16, obs_dim=3, action_dim=2)
    for i in range(20):  # past the capacity: rows 0-3 now hold transitions 16-19
        buffer.add(np.full(3, i), np.full(2, i / 100), float(i), np.full(3, i + 0.5), terminated=i % 3 == 0)
    batch = buffer.sample(64, torch.Generator().manual_seed(0))

    i = batch.reward  # each transition's index, as stored in its reward
    assert set(i.tolist()) <= set(map(float, range(4, 20))) and len(set(i.tolist())) > 8
    assert torch.equal(batch.obs, i[:, None].expand(-1, 3))
    assert torch.allclose(batch.action, (i / 100)[:, None].expand(-1, 2))
    assert torch.equal(batch.next_obs, (i + 0.5)[:, None].expand(-1, 3))
    assert torch.equal(batch.terminated, (i % 3 == 0).float())
    for name in BATCH_COLUMNS:
        column = getattr(batch, name)
        assert column.is_contiguous() and column.shape[0] == 64, name
