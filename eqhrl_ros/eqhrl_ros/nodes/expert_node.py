"""expert: serves the Advise service with a built-in controller or an exported policy.

The heuristic backend picks its controller by the env's name: ``env_id`` if set, else the
name in the env's ``env_info``. Requests that come before it knows are declined.
"""

from __future__ import annotations

import time

from rclpy.node import Node

from eqhrl_interfaces.srv import Advise

from ..core.env_spec import EnvSpec
from ..core.experts import Advice, expert_disagreements, make_expert
from .advise_msgs import answer, fill_response
from .env_info import EnvInfoWatcher, configured_spec
from .params import EXPERT_PARAMS, choices_validator, declare, reject_unknown_overrides
from .spinning import run_node


class ExpertNode(Node):
    def __init__(self, backend=None, **kwargs):
        """``backend`` (a core Expert callable) replaces the one the parameters choose."""
        super().__init__('expert', **kwargs)
        reject_unknown_overrides(self, EXPERT_PARAMS)
        self.params = declare(self, EXPERT_PARAMS)
        self.add_on_set_parameters_callback(choices_validator(EXPERT_PARAMS))
        p = self.params
        self.backend = backend
        if self.backend is None and (p['backend'] == 'policy' or p['env_id']):
            # env_id here names the controller (any env name, not only a gymnasium id).
            self.backend = self._make_backend(p['env_id'])
        self.requests = 0
        self.create_service(Advise, 'advise', self._on_request)
        # The spaces given as parameters are checked against the backend; env_id only names it.
        self.env_info = EnvInfoWatcher(
            self, configured_spec(dict(p, env_id='')), self._on_env, working=lambda: self.requests > 0
        )

    def _make_backend(self, env_name: str):
        backend = make_expert(self.params['backend'], env_name, self.params['policy_path'])
        self.get_logger().info(f"serving 'advise' with {getattr(backend, 'name', type(backend).__name__)}")
        return backend

    def _on_env(self, spec: EnvSpec) -> None:
        if self.backend is None:
            self.backend = self._make_backend(spec.name)
        differences = expert_disagreements(self.backend, spec.observation_size, spec.action_size)
        if differences:
            raise ValueError(
                f'the expert {getattr(self.backend, "name", "")!r} does not fit env {spec.name!r}: '
                + '; '.join(differences)
            )

    def _on_request(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        self.requests += 1
        name = self.get_fully_qualified_name()
        delay = self.get_parameter('response_delay_s').value
        if delay > 0:
            time.sleep(delay)
        if not self.get_parameter('enabled').value:
            return fill_response(response, Advice.decline('expert disabled (parameter enabled is false)'), name)
        if self.backend is None:
            return fill_response(response, Advice.decline(f'waiting for {self.env_info.topic}'), name)
        return answer(self.backend, request, response, name, self.get_logger())


def main(args=None):
    run_node(ExpertNode, args, name='expert')


if __name__ == '__main__':
    main()
