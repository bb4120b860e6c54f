"""learner: runs EQSACLearner on the env node's observations and asks the expert service.

Algorithm 1 in lock-step: each transition is stored and learned from (the updates) before the
next action goes out. The acting half (observations, gates, advice) is nodes/acting_node.py; this
node adds the record, checkpoints and resume. For acting and learning apart, see actor_node.py
and trainer_node.py.
"""

from __future__ import annotations

import numpy as np

from ..core.algorithm.learner import EpisodeSummary, EQSACLearner
from ..core.algorithm.learner_state import resumed_settings
from ..core.data.advice import ACTION_SOURCES
from ..core.envs.spec import EnvSpec
from ..core.runs.checkpoint import load_checkpoint
from ..core.runs.records import EpisodeRecord
from ..parameters import LEARNER_NODE_PARAMS
from .acting_node import ActingNode
from .messages import OBSERVATION_QOS
from .run_files import RunFiles, save_and_close
from .spinning import run_node

# Frames the record takes (gym_env's ~/image with the learner in the env's namespace).
IMAGE_TOPIC = 'gym_env/image'

__all__ = ['OBSERVATION_QOS', 'LearnerNode', 'main']


class LearnerNode(RunFiles, ActingNode):
    def __init__(self, **kwargs):
        super().__init__('learner', LEARNER_NODE_PARAMS, **kwargs)
        self._diverged_said = 0  # updates with a loss that is not finite, as last said in the log

    def _before_start(self) -> None:
        self._open_run_folder()

    def _prepare(self, learner: EQSACLearner, spec: EnvSpec) -> None:
        if self.params['resume']:
            # A bad checkpoint stops start-up with CheckpointError: silently starting
            # from scratch would overwrite the run the person asked to continue.
            load_checkpoint(learner, self.checkpoint_path, self.replay_path)
            self._resumed(learner)
            self._show_resumed_settings(learner)
            if self.params['prior']:
                self.get_logger().info('prior not loaded: it seeds a fresh start only (a resumed run goes on as saved)')
        elif self.params['prior']:
            self._load_prior(learner)
        # Accepted: provenance noted (with what eqhrl-report needs of a single run), a run overwritten removed only now.
        self.run_folder.begin(env=spec.name, mode=self.config.mode, seed=self.config.seed)
        with self._lock:
            self.record = EpisodeRecord(
                self.csv_path,
                EpisodeSummary.CSV_FIELDS,
                keep_before=learner.episode if self.params['resume'] else None,
            )
            if self.record.gap_warning:
                self.get_logger().warn(self.record.gap_warning)
            if self.params['record']:
                self._open_recording(learner)

    def _load_prior(self, learner: EQSACLearner) -> None:
        """Earlier runs' advice into D and D_advising (a record that does not fit refuses the start)."""
        from ..files.mcap_record import RecordError, load_prior

        observation = learner.observation
        try:
            prior = load_prior(
                self.params['prior'], observation.state_dim, learner.scaler.low, learner.scaler.high, observation.camera
            )
        except RecordError as error:
            raise ValueError(f'prior: {error}') from error
        # A file, trusted no more than the env's topic: the same limits (before, a reward of 3e38 went into D).
        beyond = self.step_limits.refusal([prior.observations, prior.next_observations], prior.rewards)
        if beyond:
            raise ValueError(f'prior: {", ".join(map(str, prior.files))}: {beyond}')
        learner.add_prior(
            prior.observations,
            prior.actions,
            prior.rewards,
            prior.next_observations,
            prior.terminated,
            prior.pixels,
            prior.next_pixels,
        )
        cut = f' ({len(prior.cut_short)} cut short, read up to their last chunk)' if prior.cut_short else ''
        self.get_logger().info(
            f'prior: {len(prior)} advised transitions from {len(prior.files)} record file(s){cut} '
            f'in D and D_advising ({len(learner.replay)} in D)'
        )

    def _open_recording(self, learner: EQSACLearner) -> None:
        from ..files.mcap_record import record_path
        from .recording import NodeRecord

        path = record_path(self.output_dir, resume=self.params['resume'])
        metadata = {'mode': self.config.mode, 'seed': self.config.seed, 'episode': learner.episode}
        self.recording = NodeRecord(self, path, metadata)
        self.recording.tap_service(self.advice.client.srv_name, self.advice.client.srv_type)
        self.recording.tap_images(IMAGE_TOPIC)
        self._transitions_topic = self.resolve_topic_name('~/transitions')
        self._recorded: list = []  # this episode's transitions, written at its end as one TransitionBatch
        self.get_logger().info(f'recording into {path}')

    def _show_resumed_settings(self, learner: EQSACLearner) -> None:
        """The budgets the run had at its save, as this node's parameters (what ros2 param get says)."""
        from rclpy.parameter import Parameter

        from ..core.algorithm.config import CONFIG_FIELDS, ros_name

        changed = []
        for name in resumed_settings(learner.config.to_dict()):
            param = ros_name(CONFIG_FIELDS[name])
            value = getattr(learner.config, name)
            if self.has_parameter(param) and self.get_parameter(param).value != value:
                changed.append(Parameter(param, value=value))
        if changed:
            self.set_parameters(changed)
            shown = ', '.join(f'{p.name} {p.value}' for p in changed)
            self.get_logger().info(f'the run goes on with {shown}, as at its last save (ros2 param set changes them)')

    def _describe(self) -> str:
        camera = self.learner and self.learner.observation.camera
        if not camera:
            return f', output {self.output_dir}'
        size = f'{camera.height}x{camera.width}x{camera.channels}'
        return f', camera {self.params["camera"]!r} {size} stacked by {camera.stack}, output {self.output_dir}'

    def _transition(self, obs, action, reward, next_obs, terminated, truncated, advised, success, source):
        summary = self.learner.step(obs, action, reward, next_obs, terminated, truncated, advised, success)
        self._say_diverged()
        if self.recording is not None:  # stored: learner.step refuses a bad one with ValueError
            normalized = self.learner.normalize(action)
            observation = self.learner.observation
            state, next_state = observation.state(obs), observation.state(next_obs)
            # A camera's: the stack acted on and the frame that followed (the record holds each frame once).
            frames = () if observation.camera is None else (obs['pixels'], next_obs['pixels'][-1])
            self._recorded.append(
                (state, normalized, reward, next_state, terminated, advised, ACTION_SOURCES.index(source), *frames)
            )
        return summary

    def _say_diverged(self) -> None:
        """Updates whose loss was not finite, said (before, silently applied): one absurd value the
        env sent stays in the replay memory and spoils every batch that draws it."""
        updater = self.learner.updater
        if updater.non_finite_updates > self._diverged_said:
            self._diverged_said = updater.non_finite_updates
            self.get_logger().warning(
                f'{updater.non_finite_updates} of {updater.updates} updates so far had a loss that is not finite: '
                'the replay memory holds a reward or observation too large for float32 arithmetic (the env sent '
                'it: check its units). Such updates were applied; a weight whose squared gradient overflowed '
                "learns no more (Adam's second moment stays infinite)",
                throttle_duration_sec=10.0,
            )

    def _write_transitions(self, summary=None) -> None:
        """The transitions stored since the last write, as the actors send them to a trainer."""
        if self.recording is None or not self._recorded:
            return
        from ..core.data.transitions import BatchFrames
        from ..core.data.transitions import TransitionBatch as Batch
        from .trainer_msgs import batch_msg

        columns = list(zip(*self._recorded))
        batch = Batch(
            actor=self.get_fully_qualified_name(),
            sequence=self.learner.episode - (summary is not None),
            observations=np.asarray(columns[0], dtype=np.float32),
            actions=np.asarray(columns[1], dtype=np.float32),
            rewards=np.asarray(columns[2], dtype=np.float32),
            next_observations=np.asarray(columns[3], dtype=np.float32),
            terminated=np.asarray(columns[4], dtype=bool),
            advised=np.asarray(columns[5], dtype=bool),
            episodes=[summary] if summary is not None else [],
            sources=np.asarray(columns[6], dtype=np.uint8),
            frames=BatchFrames.of(columns[7], columns[8]) if len(columns) > 7 else None,
        )
        self._recorded = []
        spec = self.spec
        self.recording.write(self._transitions_topic, batch_msg(batch, spec.action_low, spec.action_high))

    def _episode_done(self, summary: EpisodeSummary) -> None:
        self._append_row(summary.csv_row())
        self._write_transitions(summary)

    def close(self) -> None:
        with self._lock:
            self._write_transitions()  # an unfinished episode's transitions (they are in D)
        super().close()

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
