"""Try asking for the wheel as a person would: the real-time env, the learner, teleop_expert and
the page in one process, and a person in headless Chromium who reacts to each request after 0.6-0.8 s,
presses the deadman (Shift), steers with two key presses, drives for a while and releases.

Prints what the person got: requests, taken or ended (and what the page said), how many steps after
taking the wheel the env first applied their command, requests taken by a press from before they
appeared (0 expected), and the budget in seconds against what was spent.

    .venv/bin/python tools/try_the_wheel.py --params teleop_pendulum --seconds 60
    .venv/bin/python tools/try_the_wheel.py --params teleop_lunar_lander --seconds 60

Needs Debian's chromium and chromium-driver (make system-deps) and the venv of make setup. No
updates are made (learning_starts is set past the run), so the numbers are the protocol's alone.
"""

from __future__ import annotations

import argparse
import os
import random
import tempfile
import threading
import time

import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.parameter import Parameter

from eqhrl_interfaces.msg import AdviceRequest
from eqhrl_ros.files.paths import params_file
from eqhrl_ros.files.yaml_files import load_mapping
from eqhrl_ros.nodes.advice_console_node import AdviceConsole
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.teleop_expert_node import TeleopExpertNode
from eqhrl_ros.parameters import file_section

KEY_FOR_FIRST_ACTION = {'teleop_pendulum': 'd', 'teleop_lunar_lander': 'w'}  # raises action[0] on the page


def overrides(data: dict, node: str, **extra) -> list:
    return [Parameter(k, value=v) for k, v in {**file_section(data, node), **extra}.items()]


def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = '/usr/bin/chromium'
    for argument in ('--headless=new', '--no-sandbox', '--disable-gpu', '--window-size=1400,1000'):
        options.add_argument(argument)
    return webdriver.Chrome(service=Service('/usr/bin/chromedriver'), options=options)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--params', default='teleop_pendulum', choices=sorted(KEY_FOR_FIRST_ACTION))
    parser.add_argument('--seconds', type=float, default=60.0)
    parser.add_argument('--drive-s', type=float, default=1.5, help='how long the person drives each time')
    parser.add_argument('--budget-s', type=float, default=20.0, help="the person's budget in seconds")
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(100 + os.getpid() % 100))
    rng = random.Random(args.seed)
    data = load_mapping(params_file(args.params), 'params file')
    rclpy.init()
    out = tempfile.mkdtemp(prefix='try_the_wheel_')
    env = GymEnvNode(parameter_overrides=overrides(data, 'gym_env', publish_images=False))
    teleop = TeleopExpertNode(parameter_overrides=overrides(data, 'teleop_expert'))
    learner = LearnerNode(
        parameter_overrides=overrides(
            data,
            'learner',
            output_dir=out,
            compile_update=False,
            learning_starts=10**7,
            advising_budget_s=args.budget_s,
            mode='random',
            random_ask_rate=0.02,
        )  # fmt: skip
    )
    console = AdviceConsole(parameter_overrides=overrides(data, 'advice_console', port=0))
    applied: list = []  # (time.monotonic(), first action value) per env step
    original = env._step

    def recording(action):
        original(action)
        applied.append((time.monotonic(), float(env._previous_action[0])))

    env._step = recording
    messages: list = []  # (time.monotonic(), AdviceRequest) as the page's node hears them
    probe = rclpy.create_node('probe')
    probe.create_subscription(
        AdviceRequest, 'learner/advice_request', lambda m: messages.append((time.monotonic(), m)), 50
    )
    executor = MultiThreadedExecutor(num_threads=4)
    for node in (env, teleop, learner, console, probe):
        executor.add_node(node)
    threading.Thread(target=executor.spin, daemon=True).start()
    page = browser()
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    def text(element_id):
        return page.execute_script(
            'const e = document.getElementById(arguments[0]); return e ? e.textContent : "";', element_id
        )

    key = KEY_FOR_FIRST_ACTION[args.params]
    try:
        page.get(console.url)
        while text('connection') != 'connected':
            time.sleep(0.05)
        ActionChains(page).send_keys(key, key).perform()  # the command the person will drive with
        seen, said, presses = set(), {}, []
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            request = text('request')
            shown = text('countdown')
            if 'TAKE THE WHEEL' in request and request not in seen:
                seen.add(request)
                time.sleep(rng.uniform(0.6, 0.8))  # the person reacts
                if 'TAKE THE WHEEL' in text('request'):
                    pressed = time.monotonic()
                    ActionChains(page).key_down(Keys.SHIFT).perform()
                    presses.append(pressed)
                    time.sleep(args.drive_s)
                    ActionChains(page).key_up(Keys.SHIFT).perform()
            elif 'last request' in request:
                said[request] = shown
            time.sleep(0.05)
        time.sleep(1.0)
    finally:
        page.quit()
    wheel = [(t, m) for t, m in messages if m.wheel]
    taken = [(t, m) for t, m in wheel if m.outcome == AdviceRequest.TAKEN]
    ended = [m for _, m in wheel if m.outcome in (AdviceRequest.GIVEN, AdviceRequest.FAILED)]
    opened = {(m.episode, m.step) for _, m in wheel if m.outcome == AdviceRequest.PENDING and not m.detail}
    lags = []
    for at, msg in taken:
        person = msg.given_action[0] if len(msg.given_action) else None
        # Steps from the one the learner said TAKEN at (the first the env applied after the message)
        # to the first that carried the person's action; 0: that very step.
        first_after = next((i for i, (t, _) in enumerate(applied) if t >= at), None)
        first_person = next(
            (i for i, (t, v) in enumerate(applied) if t >= at - 0.5 and person is not None and abs(v - person) < 1e-4),
            None,
        )
        lags.append(None if first_after is None or first_person is None else first_person - first_after)
    early = sum(1 for _, m in taken if m.response_time_s < 0.1)
    spent = learner.learner.human_time_total_s
    step_s = 1.0 / env.params['rate_hz']
    print(f'{args.params}, {args.seconds:g} s at {env.params["rate_hz"]:g} Hz:')
    how = ', '.join(f'{d} {sum(1 for m in ended if m.detail == d)}' for d in sorted({m.detail for m in ended}))
    print(f'  requests for the wheel {len(opened)}; taken {len(taken)}; ended {len(ended)}: {how}')
    print(f"  steps from the learner's TAKEN to the env applying the person's action (0: the same step): {lags}")
    print(f'  taken by a press sooner than 0.1 s after the alert: {early}')
    print(f'  person seconds {spent:.2f} against a budget of {args.budget_s:g} s '
          f'(over by {max(0.0, spent - args.budget_s):.3f} s; one step is {step_s:.3f} s)')  # fmt: skip
    executor.shutdown()
    learner.close()
    for node in (env, teleop, learner, console, probe):
        node.destroy_node()
    rclpy.try_shutdown()


if __name__ == '__main__':
    main()
