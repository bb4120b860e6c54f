"""teleop_expert: a person advises through a joystick, a Twist teleop or a plain command topic.

Subscribes to ``joy`` (sensor_msgs/Joy, from the `joy` node), ``cmd_vel``
(geometry_msgs/Twist, from teleop_twist_keyboard or teleop_twist_joy) or
``teleop_command`` (std_msgs/Float32MultiArray, e.g. from keyboard_teleop), as
``source`` says, and serves ``advise`` with the latest command.
"""

from __future__ import annotations

from functools import reduce

from geometry_msgs.msg import Twist
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import Joy
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.srv import Advise

from ..core.env_spec import EnvSpec
from ..core.teleop import TWIST_FIELDS, TeleopExpert, array_command, joy_command, twist_command
from .advise_msgs import answer
from .env_info import EnvInfoWatcher, configured_spec
from .params import TELEOP_EXPERT_PARAMS, choices_validator, declare, reject_unknown_overrides
from .spinning import run_node


class TeleopExpertNode(Node):
    def __init__(self, **kwargs):
        super().__init__('teleop_expert', **kwargs)
        reject_unknown_overrides(self, TELEOP_EXPERT_PARAMS)
        self.params = declare(self, TELEOP_EXPERT_PARAMS)
        self._check_mapping(self.params)
        self.add_on_set_parameters_callback(choices_validator(TELEOP_EXPERT_PARAMS))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.expert = TeleopExpert(self.params['stale_after_s'], name=self.get_fully_qualified_name())
        self.rejected_commands = 0
        source = self.params['source']
        if source == 'joy':
            self.create_subscription(Joy, 'joy', self._on_joy, 10)
        elif source == 'twist':
            self.create_subscription(Twist, 'cmd_vel', self._on_twist, 10)
        else:
            self.create_subscription(Float32MultiArray, 'teleop_command', self._on_array, 10)
        self.create_service(Advise, 'advise', self._on_request)
        topic = {'joy': 'joy', 'twist': 'cmd_vel', 'array': 'teleop_command'}[source]
        self.get_logger().info(f"advising from '{topic}' ({source}); scales {self.params['scales']}")
        self.env_info = EnvInfoWatcher(self, configured_spec(self.params), self._check_action_size)

    def _check_action_size(self, spec: EnvSpec) -> None:
        """The mapping gives one value per entry of scales: the env must take as many."""
        n = len(self.params['scales'])
        if n != spec.action_size:
            raise ValueError(
                f"the mapping gives {n} action value(s) (parameter 'scales'), env {spec.name!r} takes "
                f'{spec.action_size}: set scales, offsets and axes (or twist_fields) for {spec.action_size}'
            )

    def _check_mapping(self, p) -> None:
        n = len(p['scales'])
        if len(p['offsets']) != n:
            raise ValueError(f"parameter 'offsets' has {len(p['offsets'])} values, 'scales' has {n}")
        if p['source'] in ('joy', 'array') and len(p['axes']) != n:
            raise ValueError(f"parameter 'axes' has {len(p['axes'])} values, 'scales' has {n}")
        if p['source'] == 'twist':
            if len(p['twist_fields']) != n:
                raise ValueError(f"parameter 'twist_fields' has {len(p['twist_fields'])} values, 'scales' has {n}")
            unknown = [f for f in p['twist_fields'] if f not in TWIST_FIELDS]
            if unknown:
                raise ValueError(f"parameter 'twist_fields' has {unknown}; known: {TWIST_FIELDS}")

    def _on_set_parameters(self, changes) -> SetParametersResult:
        updated = dict(self.params)
        updated.update({c.name: c.value for c in changes if c.name in updated})
        try:
            self._check_mapping(updated)
        except ValueError as error:
            return SetParametersResult(successful=False, reason=str(error))
        self.params = updated
        self.expert.stale_after_s = updated['stale_after_s']
        return SetParametersResult(successful=True)

    def _on_joy(self, msg: Joy) -> None:
        p = self.params
        self.expert.update(
            joy_command(
                list(msg.axes),
                list(msg.buttons),
                p['axes'],
                p['scales'],
                p['offsets'],
                p['require_enable_button'],
                p['enable_button'],
            )
        )

    def _on_twist(self, msg: Twist) -> None:
        p = self.params
        self.expert.update(
            twist_command(
                lambda field: float(reduce(getattr, field.split('.'), msg)),
                p['twist_fields'],
                p['scales'],
                p['offsets'],
            )
        )

    def _on_array(self, msg: Float32MultiArray) -> None:
        p = self.params
        try:
            self.expert.update(array_command(list(msg.data), p['axes'], p['scales'], p['offsets']))
        except ValueError as error:
            self.rejected_commands += 1
            self.get_logger().error(f"'teleop_command': {error}", throttle_duration_sec=5.0)

    def _on_request(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        return answer(self.expert, request, response, self.expert.name, self.get_logger())


def main(args=None):
    run_node(TeleopExpertNode, args, name='teleop_expert')


if __name__ == '__main__':
    main()
