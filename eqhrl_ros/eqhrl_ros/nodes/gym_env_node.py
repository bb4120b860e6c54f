"""gym_env: a gymnasium env behind Float32MultiArray topics.

Announces itself on the latched ``env_info`` (eqhrl_interfaces/msg/EnvInfo), publishes
``observation`` (obs, reward, flags, episode, step in one message) and steps when an
action arrives on ``action``: lock-step by default, or at a fixed rate holding the last
action (``realtime``), for people watching.

A person's stop (std_msgs/Bool, latched, on ``stop``) freezes it: while true, actions are
ignored and no step is taken, lock-step or real-time, so the simulated robot holds where it is
and nothing of the episode is lost; it steps on from the same state once the stop is released.
``max_action_change`` limits how far an action may move from the one before, per step.

``camera``: the env's rendering, resized, as a camera announced in env_info: each step's frame
on ``<camera>/image_raw`` just before its observation (and again with it when it is re-sent).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Optional

import numpy as np
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.node import Node
from sensor_msgs.msg import Image
from std_msgs.msg import Bool, Float32MultiArray

from eqhrl_interfaces.msg import EnvInfo

from ..core.envs.camera_envs import resized
from ..core.envs.gymnasium_envs import gym_spec, make_env
from ..core.envs.spec import EnvCamera, spec_from_parameters
from ..parameters import GYM_ENV_PARAMS
from . import env_info, messages
from .frame_msgs import image_msg
from .graph_trust import OnePublisher, subscribe_stop
from .health import OK, WARN, Check, Health
from .params import choices_validator, declare, reject_unknown_overrides
from .spinning import run_node, seconds_since_process_start, steady_clock

QOS = messages.RELIABLE_QOS  # actions in, frames out


class GymEnvNode(Node):
    def __init__(self, **kwargs):
        super().__init__('gym_env', **kwargs)
        reject_unknown_overrides(self, GYM_ENV_PARAMS)
        self.params = declare(self, GYM_ENV_PARAMS)
        self.add_on_set_parameters_callback(choices_validator(GYM_ENV_PARAMS))
        p = self.params
        rendered = p['publish_images'] or bool(p['camera'])
        self.env = make_env(p['env_id'], p['max_episode_steps'], render_mode='rgb_array' if rendered else None)
        self.spec = gym_spec(
            p['env_id'],
            p['max_episode_steps'],
            env=self.env,
            realtime=p['realtime'],
            rate_hz=p['rate_hz'] if p['realtime'] else 0.0,
        )
        self.camera = self._camera() if p['camera'] else None
        if self.camera is not None:
            self.spec = dataclasses.replace(self.spec, cameras=(self.camera,))
            self.camera_pub = self.create_publisher(
                Image, self.camera.topic, QOS, event_callbacks=PublisherEventCallbacks(matched=self._on_camera_matched)
            )
        self._camera_subscribers_seen = 0
        self._last_frame: Optional[Image] = None  # the current observation's frame, re-sent with it
        given = spec_from_parameters(p['observation_size'], p['action_low'], p['action_high'])
        if given is not None and self.spec.disagreements(given):
            raise ValueError(f'{p["env_id"]} has {"; ".join(given.disagreements(self.spec))} (parameters)')
        self.action_dim = self.spec.action_size
        self.obs_dim = self.spec.observation_size
        self.episode = 0
        self.step_index = 0
        self.steps_taken = 0
        self.rejected_actions = self.stale_actions = 0
        # Real time: steps taken with the previous action because the answer to the current
        # observation had not come by the tick (late_steps; per episode in the log).
        self.late_steps = 0
        self._episode_late = 0
        self._answered = False
        self._last_publish = time.monotonic()
        self._held_action = ((self.env.action_space.low + self.env.action_space.high) / 2).astype(np.float32)
        self._previous_action = self._held_action.copy()  # what max_action_change is measured from
        self.stopped = False
        self.stopped_actions = 0  # actions that arrived while stopped (ignored)

        self._subscribers_seen = 0
        self._started = False  # real time: the first episode's clock has started
        # The one observation message, rewritten before each publish (and re-sent as is).
        self._last_msg = None
        self._observation_out = messages.observation_out(self.obs_dim)
        self.observation_pub = self.create_publisher(
            Float32MultiArray,
            'observation',
            QOS,
            event_callbacks=PublisherEventCallbacks(matched=self._on_subscriber_matched),
        )
        # Actions arrive serialized (raw): see messages.SerializedReader.
        self._action_reader = messages.SerializedReader(messages.action_layouts(self.action_dim), 'action')
        self.create_subscription(Float32MultiArray, 'action', self._on_action, QOS, raw=True)
        # One node drives an env: while a second publishes action (a learner, a stranger), none is taken.
        self.action_source = OnePublisher(self, self.resolve_topic_name('action'))
        self.stop_guard = subscribe_stop(self, self._on_stop)  # a release only from the one publisher of /stop
        self.health = Health(self, self.health_checks)
        # Latched: nodes that start later still learn the spaces from it.
        self.env_info_pub = self.create_publisher(EnvInfo, env_info.TOPIC, env_info.ENV_INFO_QOS)
        self.env_info_pub.publish(env_info.env_info_msg(self.spec, self.get_fully_qualified_name()))
        self._reset(seed=p['seed'])
        # The steady clock: the env's pace and its re-sends must not stop with ROS time
        # (use_sim_time with no /clock). Frames are stamped with the node's clock.
        steady = steady_clock()
        if p['realtime']:
            self.create_timer(1.0 / p['rate_hz'], self._realtime_tick, clock=steady)
        else:
            self.create_timer(p['republish_period_s'], self._republish_if_idle, clock=steady)
        if p['publish_images']:
            self.image_pub = self.create_publisher(Image, '~/image', 2)
            self.create_timer(1.0 / p['image_rate_hz'], self._publish_image, clock=steady)
        self.get_logger().info(
            f'{p["env_id"]}: obs {self.obs_dim}, action {self.action_dim} in '
            f'[{self.env.action_space.low.tolist()}, {self.env.action_space.high.tolist()}], '
            f'{"real-time at %.1f Hz" % p["rate_hz"] if p["realtime"] else "lock-step"}'
        )

    def _camera(self) -> EnvCamera:
        p = self.params
        topic = self.resolve_topic_name(f'{p["camera"]}/image_raw')
        return EnvCamera(p['camera'], topic, p['camera_height'], p['camera_width'], p['camera_encoding'])

    def _publish(self) -> None:
        if self._last_frame is not None:  # the step's frame first: the learner pairs it with what follows
            self.camera_pub.publish(self._last_frame)
        self.observation_pub.publish(self._last_msg)
        self._last_publish = time.monotonic()

    def _shoot(self) -> None:
        """The camera's frame of the env as it is now (its rendering, resized)."""
        camera = self.camera
        if camera is None:
            return
        frame = resized(self.env.render(), camera.spec(1))
        self._last_frame = image_msg(frame, camera.name, self.get_clock().now().to_msg())

    def _reset(self, seed=None) -> None:
        obs, _ = self.env.reset(seed=seed)
        self.step_index = 0
        self._last_msg = self._observation_out.fill(obs, 0.0, False, False, self.episode, 0)
        self._shoot()
        self._publish()

    @property
    def refused_actions(self) -> int:
        """Actions not taken because a second node published action too."""
        return self.action_source.refused

    def health_checks(self) -> list:
        values = {'steps': self.steps_taken, 'episode': self.episode, 'rejected actions': self.rejected_actions}
        values['actions refused (two publishers)'] = self.refused_actions
        if self.stopped:
            return [Check('stop', WARN, 'STOPPED by the person: no step until released', values)]
        return [Check('stop', OK, 'running', values)]

    def _on_stop(self, msg: Bool) -> None:
        if bool(msg.data) != self.stopped:
            self.stopped = bool(msg.data)
            if self.stopped:
                self.get_logger().warn('STOPPED by the person: no step until the stop is released')
            else:
                self.get_logger().info(f'stop released: stepping on ({self.stopped_actions} actions ignored meanwhile)')
                self._publish()  # the observation the learner acts on next (the episode goes on)

    def _step(self, action: np.ndarray) -> None:
        # Inside the bounds it announced, whatever arrived (not every gymnasium env clips itself).
        action = np.clip(action, self.env.action_space.low, self.env.action_space.high).astype(np.float32)
        action = messages.rate_limited(action, self._previous_action, self.params['max_action_change'])
        self._previous_action = action
        obs, reward, terminated, truncated, _ = self.env.step(action)
        self.step_index += 1
        self.steps_taken += 1
        if self.steps_taken == 1:
            self.get_logger().info(f'first env step {seconds_since_process_start():.2f} s after the process started')
        self._last_msg = self._observation_out.fill(obs, reward, terminated, truncated, self.episode, self.step_index)
        self._shoot()
        self._publish()
        if terminated or truncated:
            if self.params['realtime']:
                self.get_logger().info(
                    f'episode {self.episode}: {self.step_index} steps, {self._episode_late} with the previous '
                    f'action (the answer came after the tick); {self.late_steps} in all'
                )
                self._episode_late = 0
            self.episode += 1
            self._reset()

    def _on_action(self, data: bytes) -> None:
        try:
            action, tag = messages.parse_action(self._action_reader.values(data), self.action_dim)
        except messages.MessageError as error:
            self.rejected_actions += 1
            self.get_logger().error(
                f'rejected action, not stepping: {error} ({self.rejected_actions} rejected so far)',
                throttle_duration_sec=5.0,
            )
            return
        if self.stopped:
            self.stopped_actions += 1
            return
        if not self.action_source.admits(self.get_logger(), 'action (not stepping)'):
            return
        if self.params['realtime']:
            self._held_action = action
            if tag is None or tag == (self.episode, self.step_index):
                self._answered = True
            return
        if tag is not None and tag != (self.episode, self.step_index):
            self.stale_actions += 1  # an answer to an observation already stepped past
            return
        self._step(action)

    def _realtime_tick(self) -> None:
        # The clock starts when the first subscriber (the learner, a person's viewer) has
        # connected: stepping for nobody would only cut the first episode short. The first
        # observation went out before anyone listened: it is sent again at that tick, and the
        # stepping begins with the next, so the first episode is seen whole.
        if self.stopped:
            return
        if self.steps_taken or self._started:
            if not self._answered:
                self.late_steps += 1
                self._episode_late += 1
            self._answered = False
            self._step(self._held_action)
        elif self._subscribers_seen:
            self._started = True
            self._publish()

    def _publish_image(self) -> None:
        if self.image_pub.get_subscription_count() == 0:
            return  # rendering costs time: only for someone watching
        frame = np.asarray(self.env.render(), dtype=np.uint8)
        self.image_pub.publish(image_msg(frame, 'gym_env', self.get_clock().now().to_msg()))

    def _on_subscriber_matched(self, info) -> None:
        # A learner that subscribes after the first observation went out would otherwise
        # wait a whole republish period for it (this was most of the start-up time).
        # Compared with the count we last saw, not with info.current_count_change: under
        # rclpy 7.1's EventsExecutor the change fields of an event that arrived before
        # spinning began read 0.
        joined = info.current_count > self._subscribers_seen
        self._subscribers_seen = info.current_count
        first_in_real_time = self.params['realtime'] and self.steps_taken == 0
        if joined and (not self.params['realtime'] or first_in_real_time) and self._last_msg is not None:
            self._publish()

    def _on_camera_matched(self, info) -> None:
        # A learner subscribes to the camera after env_info, so after the observation went out:
        # lock-step, the frame and its observation go again at once (not a republish period later).
        joined = info.current_count > self._camera_subscribers_seen
        self._camera_subscribers_seen = info.current_count
        if joined and not self.params['realtime'] and self._last_msg is not None:
            self._publish()

    def _republish_if_idle(self) -> None:
        # Nobody acted on the last observation for a whole period: a learner that
        # started late, restarted, or lost the message gets it again.
        if time.monotonic() - self._last_publish >= self.params['republish_period_s'] and not self.stopped:
            self._publish()

    def destroy_node(self):
        self.env.close()
        return super().destroy_node()


def main(args=None):
    run_node(GymEnvNode, args, name='gym_env')


if __name__ == '__main__':
    main()
