"""learner: runs EQSACLearner on the env node's observations and asks the expert service.

Algorithm 1 in lock-step: each transition is stored and learned from (the updates) before the
next action goes out. The acting half (observations, gates, advice) is nodes/acting_node.py; this
node adds the record, checkpoints and resume. For acting and learning apart, see actor_node.py
and trainer_node.py.
"""

from __future__ import annotations

from ..core.algorithm.learner import EpisodeSummary, EQSACLearner, resumed_settings
from ..core.runs.checkpoint import load_checkpoint
from ..core.runs.records import EpisodeRecord
from ..parameters import LEARNER_NODE_PARAMS
from .acting_node import OBSERVATION_QOS, ActingNode
from .run_files import RunFiles, save_and_close
from .spinning import run_node

__all__ = ['OBSERVATION_QOS', 'LearnerNode', 'main']


class LearnerNode(RunFiles, ActingNode):
    def __init__(self, **kwargs):
        super().__init__('learner', LEARNER_NODE_PARAMS, **kwargs)

    def _before_start(self) -> None:
        self._open_run_folder()

    def _prepare(self, learner: EQSACLearner) -> None:
        if self.params['resume']:
            # A bad checkpoint stops start-up with CheckpointError: silently starting
            # from scratch would overwrite the run the person asked to continue.
            load_checkpoint(learner, self.checkpoint_path, self.replay_path)
            self.get_logger().info(f'resumed from {self.checkpoint_path} at episode {learner.episode}')
            self._show_resumed_settings(learner)
        with self._lock:
            self.record = EpisodeRecord(
                self.csv_path,
                EpisodeSummary.CSV_FIELDS,
                keep_before=learner.episode if self.params['resume'] else None,
            )

    def _show_resumed_settings(self, learner: EQSACLearner) -> None:
        """The budgets the run had at its save, as this node's parameters (what ros2 param get says)."""
        from rclpy.parameter import Parameter

        from ..core.algorithm.config import FIELDS, ros_name

        changed = []
        for name in resumed_settings(learner.config.to_dict()):
            param = ros_name(FIELDS[name])
            value = getattr(learner.config, name)
            if self.has_parameter(param) and self.get_parameter(param).value != value:
                changed.append(Parameter(param, value=value))
        if changed:
            self.set_parameters(changed)
            shown = ', '.join(f'{p.name} {p.value}' for p in changed)
            self.get_logger().info(f'the run goes on with {shown}, as at its last save (ros2 param set changes them)')

    def _describe(self) -> str:
        return f', output {self.output_dir}'

    def _transition(self, obs, action, reward, next_obs, terminated, truncated, advised, success):
        return self.learner.step(obs, action, reward, next_obs, terminated, truncated, advised, success)

    def _episode_done(self, summary: EpisodeSummary) -> None:
        self._append_row(summary.csv_row())

    def _after_episode(self, summary: EpisodeSummary) -> None:
        every = self.params['checkpoint_every_episodes']
        limit = self.params['max_episodes']
        if limit and self.learner.episode >= limit:
            self.done = True
            self.save_or_log()
            self.get_logger().info(f'reached max_episodes={limit}; learning stopped')
            if self.params['shutdown_when_done']:
                self.context.try_shutdown()
        elif every and self.learner.episode % every == 0:
            self.save_or_log()


def main(args=None):
    run_node(LearnerNode, args, on_exit=save_and_close, name='learner')


if __name__ == '__main__':
    main()
