"""Asking for the wheel, in a real browser: the real-time path a person takes on the page.

gym_env (real time) -> learner (advice_protocol auto: the wheel) -> learner/advice_request ->
advice_console -> the page; the person's keys -> teleop_command -> teleop_expert ->
person_command -> the learner, which puts the person's command on the env at every step they
hold the wheel. Also an unasked takeover with T, STOP holding an open request, and the budget
in seconds, set on the page, ending a stretch within a step.
"""

import time

import pytest
from test_advice_console import Graph, browser, wait_for  # noqa: F401 (browser: the fixture)

from eqhrl_ros.nodes.advice_console_node import AdviceConsole
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.teleop_expert_node import TeleopExpertNode

from ros_helpers import applied_actions, params, small_learner_params

RATE_HZ = 30.0


@pytest.mark.alone  # a real-time env at 30 Hz and a browser, waited on by the clock
def test_a_person_takes_the_wheel_when_asked_and_the_page_tells_the_truth(browser, ros_context, tmp_path):  # noqa: F811
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    env = GymEnvNode(
        context=ros_context, parameter_overrides=params(realtime=True, rate_hz=RATE_HZ, max_episode_steps=10**6)
    )
    teleop = TeleopExpertNode(
        context=ros_context, parameter_overrides=params(source='array', axes=[0], scales=[2.0], offsets=[0.0])
    )
    learner = LearnerNode(
        context=ros_context,
        parameter_overrides=small_learner_params(
            tmp_path,
            mode='random',
            random_ask_rate=0.03,
            advising_budget=100,
            learning_starts=10**6,
            wheel_take_s=4.0,
            wheel_agree_steps=0,
            wheel_max_s=0.0,
        ),
    )
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0))
    applied = applied_actions(env)
    graph = Graph(ros_context, [env, teleop, learner, console])

    def text(element_id):
        return browser.execute_script(
            'const e = document.getElementById(arguments[0]); return e ? e.textContent : "";', element_id
        )

    def keys(*sequence):
        chain = ActionChains(browser)
        for key in sequence:
            if isinstance(key, tuple):
                (chain.key_down if key[0] == 'down' else chain.key_up)(key[1])
            else:
                chain.send_keys(key)
        chain.perform()

    def asked_to_take():
        return 'TAKE THE WHEEL' in text('request') and 'held by STOP' not in text('request')

    try:
        browser.get(console.url)
        wait_for(lambda: text('connection') == 'connected', what='the websocket')
        wait_for(lambda: 'does not take over' in text('steer-away'), what='the legend of the threshold')
        wait_for(
            lambda: browser.execute_script("return document.getElementById('wheel-keys').hidden") is False,
            what='the legend of the wheel',
        )
        assert browser.execute_script("return document.getElementById('answer-keys').hidden") is True
        assert text('driver') == 'the learner drives'
        keys(*[Keys.ARROW_LEFT] * 4)  # the command to -1: -2.0 on the env, as teleop_expert maps it

        # A deadman held from before the request never takes it: the robot stays the learner's.
        # Advice paused on the page, and no request open: the press is surely before the next one.
        browser.find_element('id', 'pause').click()
        wait_for(lambda: learner.get_parameter('advice_enabled').value is False, what='advice paused')
        wait_for(lambda: learner.wheel.open is None, timeout=10, what='no request open')
        keys(('down', Keys.SHIFT))
        pressed = time.monotonic() + 0.2  # the press has reached the learner by then
        time.sleep(0.3)
        browser.find_element('id', 'pause').click()
        wait_for(lambda: learner.get_parameter('advice_enabled').value is True, what='advice resumed')

        def alerted_after_the_press():
            open_request = learner.wheel.open
            return open_request is not None and open_request.alerted_at > pressed and asked_to_take()

        wait_for(alerted_after_the_press, what='a request for the wheel after the press')
        countdown = float(text('countdown').split()[0])
        assert 0 < countdown <= 4.0
        time.sleep(0.5)
        assert learner.wheel.open is not None and not learner.wheel.open.taken
        assert text('driver') == 'the learner drives'
        # Released and pressed again: taken, and the env gets the person's action at once.
        keys(('up', Keys.SHIFT))
        time.sleep(0.2)
        keys(('down', Keys.SHIFT))
        wait_for(lambda: 'YOU DRIVE (asked)' in text('driver'), timeout=5, what='the person driving, asked')
        at = len(applied)
        wait_for(lambda: len(applied) > at + 15, timeout=5, what='steps while driving')
        assert applied[at + 1 : at + 15] == [-2.0] * 14
        assert 'YOU HAVE THE WHEEL' in text('request')
        # The seconds driven go on while the person drives (before: '1 steps so far' all along, the
        # count of the one message that said the wheel was taken).
        driven = float(text('request').split('driving for ')[1].split(' s')[0])
        wait_for(lambda: float(text('request').split('driving for ')[1].split(' s')[0]) >= driven + 0.5, what='seconds')
        keys(('up', Keys.SHIFT))
        wait_for(lambda: text('driver') == 'the learner drives', timeout=5, what='the wheel handed back')
        wait_for(
            lambda: 'you drove' in text('recent') and 'handed back (released)' in text('recent'), what='the outcome'
        )
        counts = learner.learner.episode_advice
        assert counts.asked_steps >= 15 and counts.given == counts.human == 1

        # STOP holds an open request and its countdown; RESUME lets it go on.
        wait_for(asked_to_take, what='another request for the wheel')
        browser.find_element('id', 'stop').click()
        wait_for(lambda: 'held by STOP' in text('request'), timeout=5, what='the request held by STOP')
        held = text('countdown')
        time.sleep(1.0)
        assert text('countdown') == held and learner.wheel.open is not None and learner.wheel.open.paused_at
        browser.find_element('id', 'stop').click()
        wait_for(lambda: not env.stopped and len(applied) > 0, what='the env going on')
        wait_for(lambda: learner.wheel.open is None or learner.wheel.open.paused_at is None, what='resumed')

        # Unasked: deadman and T; the robot follows; released, it is the learner's again.
        wait_for(lambda: learner.wheel.open is None, timeout=10, what='no request open')
        keys(('down', Keys.SHIFT), ('down', 't'))
        wait_for(lambda: 'unasked' in text('driver'), timeout=5, what='an unasked takeover')
        keys(('up', 't'), ('up', Keys.SHIFT))
        wait_for(lambda: text('driver') == 'the learner drives', timeout=5, what='the takeover handed back')
        assert learner.learner.episode_advice.takeover_steps >= 1

        # The budget in seconds, set on the page: a stretch ends within one step of it.
        spent = learner.learner.human_time_total_s
        field = browser.find_element('id', 'budget-s')
        field.clear()
        field.send_keys(str(int(spent) + 3))
        browser.find_element('id', 'set-budget-s').click()
        wait_for(lambda: learner.learner.config.advising_budget_s == int(spent) + 3, what='the budget set')
        wait_for(lambda: 'left' in text('person'), what='the seconds left shown')
        wait_for(asked_to_take, timeout=30, what='a request within the budget')
        keys(('down', Keys.SHIFT))
        wait_for(lambda: 'advice is over' in text('run-state'), timeout=15, what='the budget spent')
        keys(('up', Keys.SHIFT))
        overspent = learner.learner.human_time_total_s - (int(spent) + 3)
        assert overspent <= 1.5 / RATE_HZ, overspent
        assert 'left' in text('person')

        # The console goes (the run ended): the page says so, and STOP cannot pretend to work.
        console.server.stop()
        wait_for(lambda: 'the console has stopped' in text('run-state'), timeout=10, what='the end shown')
        assert browser.execute_script("return document.getElementById('stop').disabled") is True
        assert 'not connected' in text('stop')
    finally:
        graph.close()
