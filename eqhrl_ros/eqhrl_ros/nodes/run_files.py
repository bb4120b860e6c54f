"""A learning run's files for a node (the learner, the trainer): the run folder, episodes.csv,
checkpoints and the exported policy; periodic saves that survive a full disk; the save at exit."""

from __future__ import annotations

from ..core.data.errors import CheckpointWriteError
from ..core.experts.policy import export_policy
from ..core.runs.checkpoint import check_checkpoint_file, save_checkpoint
from ..core.runs.records import RunFolder
from .spinning import ExitError, steady_clock


class RunFiles:
    """Mixed into a node that has ``params`` (parameters.run_params), ``_lock``, and, once its
    spaces are known, ``learner`` and ``record``."""

    record = None
    recording = None  # the MCAP record (record: true; nodes/recording.py)
    failed_saves = 0

    def _open_run_folder(self) -> None:
        p = self.params
        # Refuses, with one line, a folder that is a file, cannot be written, or holds a run
        # that neither resume nor overwrite was asked for.
        self.run_folder = RunFolder(p['output_dir'], resume=p['resume'], overwrite=p['overwrite'])
        self.output_dir = self.run_folder.path
        self.checkpoint_path = self.run_folder.checkpoint
        self.replay_path = self.run_folder.replay if p['save_replay'] else None
        self.csv_path = self.run_folder.episodes
        for tmp in self.run_folder.removed_temporaries:
            self.get_logger().info(f'removed {tmp}, left by a save that was interrupted')
        if p['resume']:
            # A missing or corrupt checkpoint is refused now, not after waiting for the env.
            check_checkpoint_file(self.checkpoint_path)

    def _resumed(self, learner) -> None:
        """Say where the run goes on from, and which of its settings the resume changed (before,
        a run resumed with another mode or learning rate went on with them unsaid); then
        _finished_when_resumed."""
        self.get_logger().info(f'resumed from {self.checkpoint_path} at episode {learner.episode}')
        if learner.resumed_changes:
            self.get_logger().warn(
                f'resumed with settings other than the run had at its save: {"; ".join(learner.resumed_changes)}. '
                f'The episodes from {learner.episode} on learn with them (overwrite: true starts the run anew)'
            )
        self._finished_when_resumed(learner.episode)

    def _finished_when_resumed(self, episode: int) -> None:
        """A resumed run that has already reached max_episodes learns and stores nothing more,
        not one episode more (as after the episode that reached it); one line says so."""
        limit = self.params['max_episodes']
        if limit and episode >= limit:
            self.done = True
            self.get_logger().info(
                f'the resumed run has already reached max_episodes={limit} ({episode} episodes): learning stopped '
                '(resume with a larger max_episodes to go on)'
            )
            if self.params['shutdown_when_done']:  # once spinning: the node may still be under construction
                self._shutdown_timer = self.create_timer(0.01, self._shut_down_when_done, clock=steady_clock())

    def _shut_down_when_done(self) -> None:
        self._shutdown_timer.cancel()
        self.context.try_shutdown()

    def _append_row(self, row: list) -> None:
        error = self.record.append(row)
        if error is not None:
            self.get_logger().error(
                f'{self.csv_path}: {error.strerror or error}; '
                f'{self.record.unwritten_rows} row(s) kept, written with the next one'
            )

    def save(self) -> None:
        """Checkpoint (with the replay memories if asked) and exported policy, written whole
        and renamed into place. Raises CheckpointWriteError; the previous files stay intact."""
        with self._lock:
            if self.learner is None:
                return  # the env's spaces never came: nothing learned, nothing to save
            extra = self._checkpoint_extra()
            save_checkpoint(self.learner, self.checkpoint_path, self.replay_path, extra=extra)
            export_policy(self.learner, self.run_folder.policy)
            self.record.flush()
            self._saved(extra)

    def _checkpoint_extra(self):
        """The node's own state saved with the learner's (plain values), or None."""
        return None

    def _saved(self, extra) -> None:
        """A save with ``extra`` is on disk."""

    def save_or_log(self) -> bool:
        """A periodic save: a failure (a full disk, a read-only folder) is one log line and
        training goes on; the next period tries again."""
        try:
            self.save()
        except CheckpointWriteError as error:
            self.failed_saves += 1
            self.get_logger().error(
                f'checkpoint not saved at episode {self.learner.episode}: {error} '
                '(training goes on; the previous checkpoint is intact; '
                'the next save tries again)'
            )
            return False
        return True

    def close(self) -> None:
        with self._lock:
            recording, self.recording = self.recording, None
            if recording is not None:
                recording.close()
            if self.record is None:
                return
            error = self.record.close()
            if error is not None:
                raise ExitError(
                    f'{self.csv_path}: {error.strerror or error}: the last '
                    f'{self.record.unwritten_rows} row(s) could not be written'
                )


def save_and_close(node: RunFiles) -> None:
    """At exit (the end, Ctrl-C or SIGTERM): a save that fails makes the exit code non-zero."""
    try:
        node.save()
    except CheckpointWriteError as error:
        try:
            node.close()
        except ExitError as close_error:
            node.get_logger().error(str(close_error))
        raise ExitError(f'checkpoint not saved at exit: {error}; the last saved checkpoint is intact') from error
    node.close()
    learner = node.learner
    if learner is not None:  # the last line of a run that ends well (before: nothing after the last episode)
        node.get_logger().info(
            f'saved in {node.output_dir}: {learner.episode} episodes, {learner.total_steps} steps, '
            f'{learner.updates} updates (checkpoint.pt, policy.pt, episodes.csv)'
        )
