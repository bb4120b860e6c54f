"""A run's files under faults: failed writes, paired saves, stale temporaries, bad checkpoints, folders."""

import errno
import io
import subprocess
import sys
import textwrap
import zipfile

import numpy as np
import pytest
import torch

from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig
from eqhrl_ros.core.data.errors import CheckpointError, CheckpointWriteError
from eqhrl_ros.core.runs import checkpoint as ckpt
from eqhrl_ros.core.runs import records
from eqhrl_ros.core.runs.checkpoint import load_checkpoint, save_checkpoint
from eqhrl_ros.core.runs.records import EpisodeRecord, RunFolder, RunFolderError

from process_helpers import fail_writes


def small_learner(seed=0, **overrides):
    config = LearnerConfig(
        hidden=(16, 16), batch_size=8, learning_starts=10, replay_capacity=500, seed=seed, **overrides
    )
    return EQSACLearner(3, np.array([-2.0], np.float32), np.array([2.0], np.float32), config)


def train_steps(learner, n, rng=np.random.default_rng(0)):
    for _ in range(n):
        obs = rng.normal(size=3).astype(np.float32)
        action = learner.propose(obs).action
        learner.step(obs, action, -1.0, rng.normal(size=3).astype(np.float32), False, False)


def params_of(learner):
    return [p.detach().clone() for p in (*learner.actor.parameters(), *learner.critic.parameters())]


# ------------------------------------------------------------------ writes that fail

WRITE_IN_A_SMALL_FILE_LIMIT = textwrap.dedent("""
    import resource, sys
    import numpy as np
    from eqhrl_ros.core.data.errors import CheckpointWriteError
    from eqhrl_ros.core.runs.checkpoint import save_checkpoint
    from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig
    learner = EQSACLearner(3, np.array([-2.0], np.float32), np.array([2.0], np.float32),
                           LearnerConfig(hidden=(64, 64)))
    # Files may grow to 20 KB here: a real write error (EFBIG) from the OS, as a full disk gives ENOSPC.
    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))
    try:
        save_checkpoint(learner, sys.argv[1])
    except CheckpointWriteError as error:
        print('refused:', error)
""")


@pytest.mark.slow
def test_a_save_that_the_os_refuses_is_one_clear_error_and_the_previous_file_stays(tmp_path):
    path = tmp_path / 'checkpoint.pt'
    path.write_bytes(b'previous checkpoint')
    result = subprocess.run(
        [sys.executable, '-c', WRITE_IN_A_SMALL_FILE_LIMIT, str(path)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert f'refused: cannot write {path}: File too large' in result.stdout
    assert path.read_bytes() == b'previous checkpoint'
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left behind


def test_a_failed_checkpoint_write_leaves_the_pair_untouched(tmp_path, monkeypatch):
    learner = small_learner()
    train_steps(learner, 20)
    save_checkpoint(learner, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    train_steps(learner, 5)
    fail_writes(monkeypatch, to='.checkpoint.pt.')  # the replay's write goes fine, the checkpoint's does not
    with pytest.raises(CheckpointWriteError, match='No space left on device'):
        save_checkpoint(learner, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_checkpoint_and_replay_of_two_saves_are_refused_as_a_pair(tmp_path):
    learner = small_learner()
    train_steps(learner, 20)
    save_checkpoint(learner, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    older_replay = (tmp_path / 'replay.pt').read_bytes()
    train_steps(learner, 30)
    save_checkpoint(learner, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    # As if killed between the two renames of a save: the replay of one save, the checkpoint of another.
    (tmp_path / 'replay.pt').write_bytes(older_replay)
    fresh = small_learner(seed=1)
    kept = params_of(fresh)
    with pytest.raises(CheckpointError, match='different saves'):
        load_checkpoint(fresh, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    assert all(torch.equal(a, b) for a, b in zip(kept, params_of(fresh))) and len(fresh.replay) == 0
    load_checkpoint(fresh, tmp_path / 'checkpoint.pt')  # without the replay it resumes
    assert fresh.total_steps == 50


KILLED_BETWEEN_THE_RENAMES = textwrap.dedent("""
    import os, signal, sys
    from pathlib import Path
    import numpy as np
    from eqhrl_ros.core.runs import checkpoint
    from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig
    folder = Path(sys.argv[1])
    config = LearnerConfig(hidden=(16, 16), batch_size=8, learning_starts=10, replay_capacity=500)
    learner = EQSACLearner(3, np.array([-2.0], np.float32), np.array([2.0], np.float32), config)
    rng = np.random.default_rng(0)
    def train(n):
        for _ in range(n):
            obs = rng.normal(size=3).astype(np.float32)
            learner.step(obs, learner.propose(obs).action, -1.0, rng.normal(size=3).astype(np.float32), False, False)
    train(20)
    checkpoint.save_checkpoint(learner, folder / 'checkpoint.pt', folder / 'replay.pt')
    train(30)
    replace = checkpoint.replace_file
    def killed_before_the_checkpoint(tmp, target):
        if target.name == 'checkpoint.pt':
            os.kill(os.getpid(), signal.SIGKILL)  # the new replay file is in place, the checkpoint not
        replace(tmp, target)
    checkpoint.replace_file = killed_before_the_checkpoint
    checkpoint.save_checkpoint(learner, folder / 'checkpoint.pt', folder / 'replay.pt')
""")


def test_a_save_killed_between_its_two_renames_resumes_from_the_previous_pair_with_its_replay(tmp_path):
    result = subprocess.run(
        [sys.executable, '-c', KILLED_BETWEEN_THE_RENAMES, str(tmp_path)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == -9, result.stderr[-2000:]
    RunFolder(tmp_path, resume=True).begin()  # what a node does: its stale temporaries go, its start noted
    fresh = small_learner(seed=1)
    load_checkpoint(fresh, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    assert fresh.total_steps == 20 and len(fresh.replay) == 20  # the first save, whole
    # The folder holds one pair again: the next save and resume go as usual.
    assert sorted(p.name for p in tmp_path.iterdir()) == ['checkpoint.pt', 'provenance.yaml', 'replay.pt']
    train_steps(fresh, 5)
    save_checkpoint(fresh, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    again = small_learner(seed=2)
    load_checkpoint(again, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    assert again.total_steps == 25 and len(again.replay) == 25


def test_stale_temporaries_are_removed_when_a_run_folder_is_opened(tmp_path):
    learner = small_learner()
    save_checkpoint(learner, tmp_path / 'checkpoint.pt')
    stale = [tmp_path / '.checkpoint.pt.abc123.tmp', tmp_path / '.replay.pt.x9y8.tmp']
    for path in stale:
        path.write_bytes(b'half a save')
    folder = RunFolder(tmp_path, resume=True)
    assert sorted(folder.removed_temporaries) == sorted(stale)
    assert not any(path.exists() for path in stale) and (tmp_path / 'checkpoint.pt').exists()


# ------------------------------------------------------------------ checkpoints that load but should not


def tampered(tmp_path, change):
    learner = small_learner()
    train_steps(learner, 20)
    save_checkpoint(learner, tmp_path / 'good.pt')
    state = torch.load(tmp_path / 'good.pt', weights_only=True)
    change(state)
    torch.save(state, tmp_path / 'checkpoint.pt')
    return tmp_path / 'checkpoint.pt'


def nan_actor(state):
    next(iter(state['actor'].values()))[0] = float('nan')


def list_config(state):
    state['config'] = [1, 2, 3]


def negative_episode(state):
    state['counters']['episode'] = -5


def episode_beyond_steps(state):
    state['counters']['episode'] = state['counters']['total_steps'] + 1


def inf_optimizer_moment(state):
    next(iter(state['critic_optimizer']['state'].values()))['exp_avg'].fill_(float('inf'))


def uneven_optimizer_steps(state):
    next(iter(state['actor_optimizer']['state'].values()))['step'].add_(3)


def optimizer_step_of_two_numbers(state):
    next(iter(state['critic_optimizer']['state'].values()))['step'] = torch.tensor([1.0, 2.0])


def extra_nested_too_deep(state):
    state['extra'] = '[' * 5000 + ']' * 5000  # json.loads raised RecursionError: a traceback, not a refusal


@pytest.mark.parametrize(
    'change,message',
    [
        (nan_actor, "'actor' holds non-finite"),
        (uneven_optimizer_steps, "'actor_optimizer' holds step counts"),
        (optimizer_step_of_two_numbers, "'critic_optimizer' holds a step count that is not one number"),
        (list_config, "'config' must be a dict"),
        (negative_episode, 'counters.episode must be an integer >= 0'),
        (episode_beyond_steps, 'exceeds counters.total_steps'),
        (inf_optimizer_moment, "'critic_optimizer' holds non-finite"),
        (extra_nested_too_deep, 'its extra state is not JSON'),
    ],
)
def test_checkpoints_no_run_can_produce_are_refused_and_change_nothing(tmp_path, change, message):
    path = tampered(tmp_path, change)
    fresh = small_learner(seed=3)
    kept = params_of(fresh)
    with pytest.raises(CheckpointError, match=message):
        load_checkpoint(fresh, path)
    assert all(torch.equal(a, b) for a, b in zip(kept, params_of(fresh))) and fresh.episode == 0


def test_non_finite_replay_memories_are_refused(tmp_path):
    learner = small_learner()
    train_steps(learner, 20)
    save_checkpoint(learner, tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')
    state = torch.load(tmp_path / 'replay.pt', weights_only=True)
    state['replay']['reward'][3] = float('nan')
    torch.save(state, tmp_path / 'replay.pt')
    with pytest.raises(CheckpointError, match='non-finite'):
        load_checkpoint(small_learner(), tmp_path / 'checkpoint.pt', tmp_path / 'replay.pt')


BOMB_LOAD = textwrap.dedent("""
    import resource, sys
    import numpy as np
    from eqhrl_ros.core.runs.checkpoint import CheckpointError, load_checkpoint
    from eqhrl_ros.core.algorithm.learner import EQSACLearner, LearnerConfig
    learner = EQSACLearner(3, np.array([-2.0], np.float32), np.array([2.0], np.float32),
                           LearnerConfig(hidden=(16, 16)))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    try:
        load_checkpoint(learner, sys.argv[1])
    except CheckpointError as error:
        print('refused:', error)
    print('peak grew MB', (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024)
""")


@pytest.mark.slow
def test_a_deflate_bomb_is_refused_before_it_is_unpacked(tmp_path):
    path = tmp_path / 'checkpoint.pt'
    with zipfile.ZipFile(path, 'w', compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr('archive/data.pkl', io.BytesIO().getvalue())
        archive.writestr('archive/data/0', bytes(256 << 20))  # 256 MB of zeros, ~256 KB packed
    assert path.stat().st_size < 1 << 20
    result = subprocess.run([sys.executable, '-c', BOMB_LOAD, str(path)], capture_output=True, text=True, timeout=120)
    assert 'refused:' in result.stdout and 'is compressed' in result.stdout, result.stdout + result.stderr[-2000:]
    grew = float(result.stdout.split('peak grew MB')[1])
    assert grew < 50, result.stdout


def test_a_file_larger_than_the_learner_can_need_is_refused_unread(tmp_path, monkeypatch):
    learner = small_learner()
    save_checkpoint(learner, tmp_path / 'checkpoint.pt')
    limit = ckpt.checkpoint_size_limit(learner)
    with (tmp_path / 'checkpoint.pt').open('ab') as f:
        f.write(bytes(limit))  # still a zip (trailing data), far too large
    loaded = []
    monkeypatch.setattr(ckpt.torch, 'load', lambda *a, **k: loaded.append(1))
    with pytest.raises(CheckpointError, match="more than the .* that this learner's sizes can need"):
        load_checkpoint(small_learner(), tmp_path / 'checkpoint.pt')
    assert loaded == []


# ------------------------------------------------------------------ run folders and the record


def test_a_folder_that_holds_a_run_is_refused_unless_resumed_or_overwritten(tmp_path):
    (tmp_path / 'episodes.csv').write_text('episode\n0\n')
    with pytest.raises(RunFolderError, match=r'holds a run \(episodes.csv\).*resume.*overwrite'):
        RunFolder(tmp_path)
    folder = RunFolder(tmp_path, overwrite=True)
    assert (tmp_path / 'episodes.csv').exists()  # kept until the start is accepted
    folder.begin()
    assert not (tmp_path / 'episodes.csv').exists()
    RunFolder(tmp_path)  # now empty: a fresh run may start


def test_folders_that_cannot_be_used_are_refused_with_one_line(tmp_path):
    a_file = tmp_path / 'not_a_folder'
    a_file.write_text('x')
    with pytest.raises(RunFolderError, match='is a file'):
        RunFolder(a_file)
    with pytest.raises(RunFolderError, match='cannot be written'):
        RunFolder(a_file / 'run')
    with pytest.raises(RunFolderError, match='nothing to resume'):
        RunFolder(tmp_path / 'empty', resume=True)
    assert not (tmp_path / 'empty').exists()  # before, the refused resume left the folder made
    (tmp_path / 'run').mkdir()
    (tmp_path / 'run' / 'episodes.csv').write_text('episode\n0\n')
    with pytest.raises(RunFolderError, match='resume and overwrite both given'):  # before: resume won, unsaid
        RunFolder(tmp_path / 'run', resume=True, overwrite=True)
    assert (tmp_path / 'run' / 'episodes.csv').exists()


def test_a_fresh_record_is_there_with_its_header_before_the_first_row(tmp_path, monkeypatch):
    """A reader (a test's wait, a user's pandas) that looks before the first episode ends finds the
    header, never an empty file: csv.DictReader on a file empty when it looked took the first row
    for the header. Where the header cannot be written, it comes with the first row."""
    path = tmp_path / 'episodes.csv'
    path.write_text('old,run\n')
    record = EpisodeRecord(path, ('episode', 'return'))
    assert path.read_bytes() == b'episode,return\r\n' and not path.with_suffix('.csv.tmp').exists()
    record.append([0, '-1.5'])
    record.close()
    assert path.read_bytes() == b'episode,return\r\n0,-1.5\r\n'

    fail_writes(monkeypatch, 'episodes.csv.tmp')  # the header's write fails; the rows' do not
    record = EpisodeRecord(path, ('episode', 'return'))
    assert path.read_bytes() == b''  # the old run is gone all the same
    record.append([0, '-2.5'])
    record.close()
    assert path.read_bytes() == b'episode,return\r\n0,-2.5\r\n'


def test_a_row_that_cannot_be_written_is_kept_and_written_whole_later(tmp_path, monkeypatch):
    record = EpisodeRecord(tmp_path / 'episodes.csv', ('episode', 'return'))
    assert record.append([0, '-1.5']) is None
    real = records.os.write

    def half_then_full_disk(fd, data):
        monkeypatch.setattr(records.os, 'write', full_disk)
        return real(fd, data[:3])  # a torn write, then ENOSPC

    def full_disk(fd, data):
        raise OSError(errno.ENOSPC, 'No space left on device')

    monkeypatch.setattr(records.os, 'write', half_then_full_disk)
    error = record.append([1, '-2.5'])
    assert error is not None and error.errno == errno.ENOSPC and record.unwritten_rows == 1
    monkeypatch.setattr(records.os, 'write', real)  # space again
    assert record.append([2, '-3.5']) is None and record.unwritten_rows == 0
    record.close()
    assert (tmp_path / 'episodes.csv').read_bytes().decode() == 'episode,return\r\n0,-1.5\r\n1,-2.5\r\n2,-3.5\r\n'


def test_resume_keeps_rows_before_the_checkpoint_and_drops_torn_ones(tmp_path):
    path = tmp_path / 'episodes.csv'
    path.write_text('episode,return\n0,-1\n1,-2\n2,-3\n3,-4\n4,-')
    record = EpisodeRecord(path, ('episode', 'return'), keep_before=3)
    record.append([3, '-9'])
    record.close()
    assert path.read_text().split() == ['episode,return', '0,-1', '1,-2', '2,-3', '3,-9']
    assert record.missing == [] and record.gap_warning == ''  # a torn row of an episode redone is no loss


def test_a_resume_says_which_episodes_have_no_whole_row_before_the_checkpoint(tmp_path):
    """A row torn by a kill during its write (or lost with the disk) before the resume point was
    dropped without a word, leaving a gap in the record that no one was told of."""
    path = tmp_path / 'episodes.csv'
    path.write_text('episode,return\n0,-1\n1\n3,-4\n4,-')  # episode 4's row torn inside its last value
    record = EpisodeRecord(path, ('episode', 'return'), keep_before=5)
    record.close()
    assert path.read_text().split() == ['episode,return', '0,-1', '3,-4']
    assert record.missing == [1, 2, 4]
    assert record.gap_warning.startswith(f'{path}: no whole row for episode(s) 1, 2, 4 (a row torn by a kill')
