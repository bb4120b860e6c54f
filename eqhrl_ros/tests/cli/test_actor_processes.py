"""Actors and a trainer as separate processes, as on several machines: an actor
that dies leaves the others going; a trainer that dies leaves the actors acting and keeping
their transitions; a trainer restarted with resume continues and the actors take its weights."""

import signal

import pytest

from process_helpers import output, read_rows, settled, start, stop, wait_for

pytestmark = pytest.mark.slow

SMALL = ['-p', 'env_id:=Pendulum-v1', '-p', 'hidden_sizes:=[16,16]', '-p', 'batch_size:=16']
SMALL += ['-p', 'learning_starts:=50', '-p', 'mode:=sac', '-p', 'torch_threads:=1']


def start_actor(index, log_dir, *extra):
    ns = ['--ros-args', '-r', f'__ns:=/actor{index}']
    env = start('gym_env', *ns, '-p', 'max_episode_steps:=25', '-p', f'seed:={index}', log_dir=log_dir)
    actor = start('actor', *ns, *SMALL, '-p', f'seed:={index}', '-p', 'flush_period_s:=0.1', *extra, log_dir=log_dir)
    return env, actor


def start_trainer(out, log_dir, *extra):
    return start(
        'trainer',
        '--ros-args',
        *SMALL,
        '-p',
        f'output_dir:={out}',
        '-p',
        'checkpoint_every_episodes:=1',
        '-p',
        'save_replay:=true',
        '-p',
        'weights_every_updates:=10',
        '-p',
        'actor_silence_s:=1.5',
        '-p',
        'report_period_s:=0.5',
        '-p',
        'actors:=[/actor0/actor, /actor1/actor]',  # whom it hears (a stranger under another name: refused)
        *extra,
        log_dir=log_dir,
    )


def rows_from(out, actor):
    path = out / 'episodes.csv'
    return [r for r in read_rows(path) if r['actor'] == actor] if path.exists() else []


def catching_up(finished, out, actor, trainer) -> str:
    """What to read when the trainer has not caught up with the actor: the counts, the trainer's
    last report and the actor's last lines (CI once stopped short of every episode, unexplained)."""
    reports = [line for line in output(trainer).splitlines() if 'batches lost' in line]
    actor_lines = [line for line in output(actor).splitlines() if ']: episode ' not in line]
    return '\n'.join(
        [f'actor finished {finished}, trainer stored {len(rows_from(out, "/actor0/actor"))}', *reports[-1:]]
        + actor_lines[-15:]
    )


def test_an_actor_that_dies_leaves_the_others_learning(tmp_path):
    out = tmp_path / 'run'
    processes = [start_trainer(out, tmp_path)]
    try:
        processes += [*start_actor(0, tmp_path), *start_actor(1, tmp_path)]
        assert wait_for(
            lambda: len(rows_from(out, '/actor1/actor')) >= 2 and len(rows_from(out, '/actor0/actor')) >= 2, 90
        )
        processes[4].send_signal(signal.SIGKILL)  # actor 1, without a word
        before = len(rows_from(out, '/actor0/actor'))
        trainer = processes[0]
        assert wait_for(lambda: 'actor /actor1/actor has sent nothing for' in output(trainer), 30), output(trainer)
        assert wait_for(lambda: len(rows_from(out, '/actor0/actor')) >= before + 3, 30)
        assert trainer.poll() is None
        reports = [line for line in output(trainer).splitlines() if 'batches lost' in line]
        assert reports and ', 0 batches lost' in reports[-1], reports[-1:]
    finally:
        logs = [stop(p) for p in processes]
    assert 'updates' in logs[0]


def test_actors_outlive_their_trainer_and_take_the_weights_of_the_next(tmp_path):
    out = tmp_path / 'run'
    trainer = start_trainer(out, tmp_path)
    env, actor = start_actor(0, tmp_path)
    processes = [trainer, env, actor]
    try:
        # A row is written as its episode is stored, the checkpoint at the end of that learning step:
        # under load the kill can fall between them, and there is then nothing to resume.
        saved = out / 'checkpoint.pt'
        assert wait_for(lambda: len(rows_from(out, '/actor0/actor')) >= 3 and saved.exists(), 90), output(trainer)
        trainer.send_signal(signal.SIGKILL)  # no save at exit: the last periodic checkpoint counts
        trainer.wait()
        saved_rows = len(rows_from(out, '/actor0/actor'))
        # The actor goes on acting (its episodes keep coming) and keeps what it cannot send. It
        # notices once DDS drops the killed trainer from the graph: often at once, but up to Fast
        # DDS's participant lease (20 s) later; CI once saw 21 s. (A trainer announcing a 3 s lease,
        # through a Fast DDS profile, made this test 24 s shorter, but the resumed trainer then fell
        # short of the actor's episodes in 2 of 3 full runs: see catching_up.)
        assert wait_for(lambda: 'no trainer on /transitions' in output(actor), 45), output(actor)
        episodes_then = output(actor).count('] [actor0.actor]: episode ')
        assert wait_for(lambda: output(actor).count('] [actor0.actor]: episode ') >= episodes_then + 3, 30)

        restarted = start_trainer(out, tmp_path, '-p', 'resume:=true')
        processes.append(restarted)
        assert wait_for(lambda: 'resumed from' in output(restarted), 60), output(restarted)
        assert wait_for(lambda: 'a trainer listens on /transitions' in output(actor), 30), output(actor)
        assert wait_for(lambda: 'weights every' in output(restarted), 30), output(restarted)  # its id's line
        new_id = output(restarted).split(' trainer ', 1)[1].split(':', 1)[0]
        assert wait_for(lambda: f"weights from trainer '{new_id}" in output(actor), 30), output(actor)
        assert wait_for(lambda: len(rows_from(out, '/actor0/actor')) >= saved_rows + 3, 60)
        # Every episode the actor finished is in the record exactly once: those the killed trainer
        # stored after its last checkpoint, and those made while no trainer listened, were kept
        # by the actor until a checkpoint held them, and sent again to the resumed trainer.
        stop(env)  # the robot stops: the actor finishes no more episodes, and sends what it keeps
        # The env's last message may still be in the actor's hands when the env has exited: count
        # its episodes once its log has been quiet for a while (CI once counted one too early).
        finished = settled(lambda: output(actor).count('] [actor0.actor]: episode '), quiet_s=2.0, timeout=30)
        # The resumed trainer stores again all the actor kept, with a save after every episode
        # (checkpoint_every_episodes 1, save_replay): under load, more than a minute at times.
        assert wait_for(lambda: len(rows_from(out, '/actor0/actor')) >= finished, 120), catching_up(
            finished, out, actor, restarted
        )
        stored = len(rows_from(out, '/actor0/actor'))
        assert stored == finished, (stored, finished)
    finally:
        logs = [stop(p) for p in processes]
    rows = read_rows(out / 'episodes.csv')
    assert [int(r['episode']) for r in rows] == list(range(len(rows)))  # the record continues, no gap
    exit_line = [line for line in logs[2].splitlines() if 'sent' in line and 'dropped' in line][-1]
    assert ' 0 dropped' in exit_line, exit_line
