"""expert: serves the Advise service with a built-in controller, an exported policy, or a
simulated person imitating either.

The heuristic backend picks its controller by the env's name: ``env_id`` if set, else the
name in the env's ``env_info``. It serves 'advise' once it knows (a server that is there can
answer: a learner waits for one, start_wait.py, and would not for a node bound to decline). The
simulated person's reaction time is waited out on the steady clock in a coroutine, so the
node stays responsive meanwhile (its service has its own callback group).
"""

from __future__ import annotations

import time
from typing import Optional

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from eqhrl_interfaces.srv import Advise

from ..core.data.advice import Advice
from ..core.data.camera_frames import FrameError
from ..core.data.signing import signer_from
from ..core.envs.spec import EnvSpec
from ..core.experts.controllers import expert_disagreements
from ..core.experts.factory import make_expert
from ..core.experts.simulated_human import HumanLimits, SimulatedHuman
from ..parameters import EXPERT_PARAMS, HUMAN_LIMIT_PARAMS
from .advise_msgs import (
    answer,
    fill_response,
    frames_refused,
    request_check,
    request_from_msg,
    request_refusal,
    sign_answer,
    unsigned_request,
)
from .env_info import EnvInfoWatcher, configured_spec, shown
from .params import choices_validator, declare, reject_unknown_overrides
from .recording import introspect
from .spinning import pause, run_node, steady_clock
from .teleop_expert_node import ANSWER_MARGIN_S


class ExpertNode(Node):
    def __init__(self, backend=None, **kwargs):
        """``backend`` (a core Expert callable) replaces the one the parameters choose."""
        super().__init__('expert', **kwargs)
        reject_unknown_overrides(self, EXPERT_PARAMS)
        self.params = declare(self, EXPERT_PARAMS)
        self.add_on_set_parameters_callback(choices_validator(EXPERT_PARAMS))
        p = self.params
        # With key_file: only requests signed with it are answered, and each answer is signed for its
        # request (KeyFileError, a ValueError, refuses the node at start-up).
        self.request_check = request_check(signer_from(p['key_file'], self.get_logger().warning))
        self.backend = backend
        if self.backend is None and (p['backend'] == 'policy' or p['env_id']):
            # env_id here names the controller (any env name, not only a gymnasium id).
            self.backend = self._make_backend(p['env_id'])
        self.requests = 0
        self._steady = steady_clock()
        # A simulated person answers from a coroutine (it waits out a reaction time); the
        # others answer at once. Coroutine callbacks need an executor that runs them.
        self.coroutine_callbacks = p['backend'] == 'simulated_human'
        self.service = None
        if self.backend is not None:
            self._serve()
        # The spaces given as parameters are checked against the backend; env_id only names it.
        self.env_info = EnvInfoWatcher(
            self, configured_spec(dict(p, env_id='')), self._on_env, working=lambda: self.requests > 0
        )

    def _serve(self) -> None:
        self.service = self.create_service(
            Advise,
            'advise',
            self._on_request_as_person if self.coroutine_callbacks else self._on_request,
            callback_group=ReentrantCallbackGroup(),
        )
        introspect(self.service, self)  # every call on advise/_service_event (ros2 bag record, the learner's record)

    def _make_backend(self, env_name: str):
        p = self.params
        limits = HumanLimits(**{param.name: p[param.name] for param in HUMAN_LIMIT_PARAMS})
        backend = make_expert(p['backend'], env_name, p['policy_path'], limits, p['seed'])
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
        if self.service is None:
            self._serve()

    def _refusal(self, request: Advise.Request) -> Optional[Advice]:
        """Why this request gets no answer from the backend, if it does not."""
        self.requests += 1
        delay = self.get_parameter('response_delay_s').value
        if delay > 0:
            time.sleep(delay)
        if not self.get_parameter('enabled').value:
            return Advice.decline('expert disabled (parameter enabled is false)')
        # The sizes the env announced, else those the backend was written for (a controller by name).
        spec, backend = self.env_info.spec, self.backend
        obs_size = spec.observation_size if spec else getattr(backend, 'observation_size', None)
        action_size = spec.action_size if spec else getattr(backend, 'action_size', None)
        env = shown(spec.name) if spec else self.params['env_id'] or 'env'
        sizes = {
            'observation': (len(request.observation), obs_size),
            'proposed_action': (len(request.proposed_action), action_size),
            'action_low': (len(request.action_low), action_size),
            'action_high': (len(request.action_high), action_size),
        }
        for field, (got, want) in sizes.items():
            if want is not None and got != want:
                return Advice.decline(f'{field} has {got} values; the env {env!r} has {want}')
        refusal = request_refusal(request)
        if refusal:
            return Advice.decline(refusal)
        if spec is not None:  # an answer is made in the env's units: outside bounds that are not the env's
            asked = EnvSpec(spec.name, spec.observation_size, request.action_low, request.action_high)
            differences = spec.disagreements(asked)
            if differences:
                return Advice.decline(f'the request has {differences[0]} (the env {env!r})')
        return None

    def _on_request(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        unsigned = unsigned_request(
            request, response, self.request_check, self.get_fully_qualified_name(), self.get_logger()
        )
        if unsigned is not None:
            return unsigned
        name = self.get_fully_qualified_name()
        refusal = self._refusal(request)
        if refusal is not None:
            return sign_answer(fill_response(response, refusal, name), request, self.request_check)
        return sign_answer(
            answer(self.backend, request, response, name, self.get_logger()), request, self.request_check
        )

    async def _on_request_as_person(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        unsigned = unsigned_request(
            request, response, self.request_check, self.get_fully_qualified_name(), self.get_logger()
        )
        if unsigned is not None:
            return unsigned
        return sign_answer(await self._as_person(request, response), request, self.request_check)

    async def _as_person(self, request: Advise.Request, response: Advise.Response) -> Advise.Response:
        """The simulated person reacts after their drawn delay, within the answer window
        (cut, like teleop_expert's, to the learner's timeout)."""
        name = self.get_fully_qualified_name()
        refusal = self._refusal(request)
        if refusal is not None:
            return fill_response(response, refusal, name)
        human: SimulatedHuman = self.backend
        window = human.limits.answer_window_s
        if request.timeout_s > 0:
            window = max(0.0, min(window, request.timeout_s - ANSWER_MARGIN_S))
        if window < human.limits.reaction_median_s:
            self.get_logger().warn(
                f'the learner waits {request.timeout_s:.2f} s for an answer, and the simulated person reacts in '
                f'{human.limits.reaction_median_s:.2f} s (median): most requests will time out. Give the learner '
                'a longer advice_timeout_s (e.g. params/teleop_pendulum.yaml, 5 s)',
                throttle_duration_sec=30.0,
            )
        try:
            asked = request_from_msg(request)
        except FrameError as error:
            return fill_response(response, frames_refused(error, self.get_logger()), name)
        plan = human.plan(asked)
        await pause(self, min(plan.delay_s, window), self._steady)
        return fill_response(response, human.outcome(plan, window), name)


def main(args=None):
    run_node(ExpertNode, args, name='expert')


if __name__ == '__main__':
    main()
