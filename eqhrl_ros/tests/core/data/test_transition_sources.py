"""Who chose each stored action travels with the transitions (TransitionBatch.sources): the
learner, an expert's answer, the person asked to take the wheel, or a takeover."""

from types import SimpleNamespace

import numpy as np
import pytest

from eqhrl_ros.core.data.advice import ACTION_SOURCES
from eqhrl_ros.core.data.transitions import BatchError, Outbox, batch_fields, batch_from_fields


def sealed_batch(sources):
    outbox = Outbox('a0', 3, 1, batch_transitions=100, limit=1000)
    for i, source in enumerate(sources):
        outbox.add(np.full(3, i, np.float32), np.zeros(1, np.float32), 0.0, np.zeros(3, np.float32), False,
                   source != 'learner', source)  # fmt: skip
    outbox.seal()
    return outbox.sealed[-1]


def test_an_actors_batch_says_who_chose_each_action_and_reads_back():
    batch = sealed_batch(['learner', 'asked', 'asked', 'takeover', 'answer'])
    assert [ACTION_SOURCES[i] for i in batch.sources] == ['learner', 'asked', 'asked', 'takeover', 'answer']
    fields = batch_fields(batch, [-2.0], [2.0])
    back, _, _ = batch_from_fields(SimpleNamespace(**fields, signature=b''))
    assert back.sources.tolist() == batch.sources.tolist()


def test_sources_of_the_wrong_length_or_out_of_range_are_refused_and_none_is_allowed():
    fields = batch_fields(sealed_batch(['learner', 'asked']), [-2.0], [2.0])
    with pytest.raises(BatchError, match='sources has 1 values'):
        batch_from_fields(SimpleNamespace(**{**fields, 'sources': [2]}))
    with pytest.raises(BatchError, match='not an index'):
        batch_from_fields(SimpleNamespace(**{**fields, 'sources': [0, 9]}))
    older, _, _ = batch_from_fields(SimpleNamespace(**{**fields, 'sources': []}))  # a sender from before
    assert len(older.sources) == 0 and len(older) == 2
