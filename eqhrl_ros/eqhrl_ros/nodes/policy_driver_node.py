"""policy_driver: the env driven by a policy a learner or trainer exported (policy.pt), learning nothing.

What a trained run is for: the robot driven by what it learned, with no advice, no updates and no
exploration. For each observation the node publishes the policy's deterministic action
tanh(mean), in the env's units, tagged with the step it answers; an observation the env sends
again (its action was lost) gets the same action again. It logs each episode's return, length
and success (the env's verdict where its observation carries one, else the env's success rule,
as the learner judges it), and with max_episodes stops after that many, saying their mean return
and success rate.

The spaces come from the env's env_info (or env_id, or the spaces parameters) and must be the
policy's: another observation size or other action bounds stop the node with one line. Like the
learner, it takes observations only while one node publishes them (env_node, if named). A camera
policy needs its frames, which this node does not read: serve such a policy with `expert
--ros-args -p backend:=policy`.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import torch
from rclpy.node import Node
from std_msgs.msg import Float32MultiArray

from ..core.envs.spec import EnvSpec
from ..core.experts.policy import PolicyExpert
from ..parameters import POLICY_DRIVER_PARAMS
from . import messages
from .env_info import EnvInfoWatcher, configured_spec, shown
from .graph_trust import OnePublisher
from .params import declare, reject_unknown_overrides
from .spinning import run_node


class PolicyDriverNode(Node):
    def __init__(self, **kwargs):
        super().__init__('policy_driver', **kwargs)
        reject_unknown_overrides(self, POLICY_DRIVER_PARAMS)
        self.params = p = declare(self, POLICY_DRIVER_PARAMS)
        if not p['policy_path']:
            raise ValueError('policy_path is required: the policy.pt a learner or trainer exported into its run folder')
        torch.set_num_threads(1)  # one observation at a time: a second thread only waits
        self.policy = PolicyExpert(p['policy_path'])  # a broken or non-finite file: refused here, in one line
        if self.policy.camera is not None:
            raise ValueError(
                f'{p["policy_path"]}: a camera policy reads frames, which policy_driver does not; serve it with '
                'expert --ros-args -p backend:=policy'
            )
        self.spec: Optional[EnvSpec] = None
        self.action_pub = self.create_publisher(Float32MultiArray, 'action', messages.RELIABLE_QOS)
        subscription = self.create_subscription(
            Float32MultiArray, 'observation', self._on_observation, messages.OBSERVATION_QOS
        )
        self.observation_source = OnePublisher(self, subscription.topic_name, p['env_node'])
        self._last: Optional[tuple] = None  # ((episode, step), action) of the last observation answered
        self.episode_return, self.episode_length = 0.0, 0
        self.returns: list[float] = []
        self.dropped = 0
        self.env_info = EnvInfoWatcher(self, configured_spec(p), self._on_env, working=lambda: self._last is not None)

    def _on_env(self, spec: EnvSpec) -> None:
        policy = EnvSpec(spec.name, self.policy.obs_dim, self.policy.scaler.low, self.policy.scaler.high)
        differences = spec.disagreements(policy)
        if differences:
            raise ValueError(
                f'the policy {self.params["policy_path"]} does not fit env {shown(spec.name)!r}: '
                + '; '.join(differences)
            )
        self.spec = spec
        self.success = spec.success_criterion()  # the env's verdict, where its observation carries one, wins
        self.successes = 0
        self.get_logger().info(
            f'driving {shown(spec.name)} with {self.params["policy_path"]} (deterministic; nothing learned, '
            'nothing asked)'
        )

    def _on_observation(self, msg: Float32MultiArray) -> None:
        if self.spec is None or self.done:
            return
        if not self.observation_source.admits(self.get_logger(), 'observation'):
            return
        try:
            step = messages.parse_observation(msg, self.spec.observation_size)
        except messages.MessageError as error:
            self.dropped += 1
            self.get_logger().error(f'dropped observation: {error}', throttle_duration_sec=5.0)
            return
        key = (step.episode, step.step)
        if self._last is not None and key == self._last[0]:
            if self._last[1] is not None:  # the env did not get our action: the same again
                self.action_pub.publish(messages.action_msg(self._last[1], *key))
            return  # (a final observation sent again wants none)
        if step.step == 0:
            self.success.reset()
        else:  # the step our last action made
            self.episode_return += step.reward
            self.episode_length += 1
            self.success.update(step.obs, step.reward)
        if step.done:
            self._episode_ends(step)
            self._last = (key, None)
            return
        action = self.policy.action(step.obs)
        self._last = (key, action)
        self.action_pub.publish(messages.action_msg(action, *key))

    def _episode_ends(self, step: messages.EnvStep) -> None:
        self.returns.append(self.episode_return)
        success = self.success.success(self.episode_return) if step.success is None else step.success
        self.successes += int(success)
        self.get_logger().info(
            f'episode {step.episode:4d}  return {self.episode_return:9.2f}  len {self.episode_length:4d}  '
            f'success {int(success)}'
        )
        self.episode_return, self.episode_length = 0.0, 0
        if self.done:
            self.get_logger().info(f'{self.summary()}; stopping')
            self.context.try_shutdown()

    def summary(self) -> str:
        n = len(self.returns)
        return (
            f'drove {n} episodes: mean return {np.mean(self.returns):.2f} (min {min(self.returns):.2f}, '
            f'max {max(self.returns):.2f}), success {self.successes / n:.0%}'
        )

    def destroy_node(self) -> None:
        """At Ctrl-C or SIGTERM (run_node destroys the node), the episodes driven so far, in one line."""
        if self.returns and not self.done:
            self.get_logger().info(self.summary())
        super().destroy_node()

    @property
    def done(self) -> bool:
        limit = self.params['max_episodes']
        return bool(limit) and len(self.returns) >= limit


def main(args=None):
    run_node(PolicyDriverNode, args, name='policy_driver')


if __name__ == '__main__':
    main()
