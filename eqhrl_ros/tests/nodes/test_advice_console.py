"""advice_console in a real browser: Debian's chromium, headless, driven by selenium.

The whole person's path runs: gym_env (lock-step, frames on) -> learner (QASAC) -> advise ->
teleop_expert (answer window) <- teleop_command <- advice_console <- the page <- keys and a
gamepad. The nodes spin in a thread of this process, so the test reads the learner's counts.
"""

import math
import os
import re
import socket
import threading
import time
from pathlib import Path

import pytest
from rclpy.executors import SingleThreadedExecutor

from eqhrl_ros.core.data.advice import SKIPPED
from eqhrl_ros.nodes.advice_console_node import AdviceConsole, is_loopback
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.spinning import start_up_errors
from eqhrl_ros.nodes.teleop_expert_node import TeleopExpertNode

from ros_helpers import params, rosout_listener, small_learner_params

CHROMIUM, CHROMEDRIVER = '/usr/bin/chromium', '/usr/bin/chromedriver'
# The screenshot in the docs comes from this test: EQHRL_CONSOLE_SCREENSHOT=docs/images/advice_console.png
SCREENSHOT = os.environ.get('EQHRL_CONSOLE_SCREENSHOT')


@pytest.fixture
def browser():
    if not (os.path.exists(CHROMIUM) and os.path.exists(CHROMEDRIVER)):
        pytest.fail("this test needs Debian's chromium and chromium-driver: apt-get install chromium chromium-driver")
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = CHROMIUM
    for argument in ('--headless=new', '--no-sandbox', '--disable-gpu', '--disable-dev-shm-usage'):
        options.add_argument(argument)
    options.add_argument('--window-size=1400,1000')
    options.set_capability('goog:loggingPrefs', {'browser': 'ALL'})  # the page's console, read by tests
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()


class Graph:
    """Nodes spun by one executor in a background thread."""

    def __init__(self, context, nodes):
        self.nodes = nodes
        self.executor = SingleThreadedExecutor(context=context)
        for node in nodes:
            self.executor.add_node(node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # the context shuts down at the end of the test
            pass

    def close(self):
        self.executor.shutdown()
        self.thread.join(timeout=5)
        for node in self.nodes:
            if isinstance(node, LearnerNode):
                node.close()
            node.destroy_node()


def wait_for(condition, timeout=20.0, what=''):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f'timed out waiting for {what() if callable(what) else what or condition}')


def shown_as_text(browser, text, *where):
    """``text`` (another node's words, with an <img onerror>) appears as text in the first element
    of ``where``, and no element was made of it, so no script of its ran."""
    shown = f"return document.getElementById('{where[0]}').textContent"
    wait_for(lambda: text in browser.execute_script(shown), what=f'{text!r} shown as text in #{where[0]}')
    images = ', '.join(f'#{element} img' for element in where)
    assert browser.execute_script(f"return document.querySelectorAll('{images}').length") == 0
    assert browser.execute_script('return window.ran') is None


def test_a_person_advises_from_the_browser(browser, ros_context, tmp_path):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    env = GymEnvNode(
        context=ros_context, parameter_overrides=params(max_episode_steps=40, publish_images=True, image_rate_hz=10.0)
    )
    teleop = TeleopExpertNode(
        context=ros_context,
        parameter_overrides=params(source='array', axes=[0], scales=[2.0], offsets=[0.0], answer_window_s=2.5),
    )
    learner = LearnerNode(
        context=ros_context,
        parameter_overrides=small_learner_params(tmp_path, mode='qasac', advising_budget=100, advice_timeout_s=3.0),
    )
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0))
    graph = Graph(ros_context, [env, teleop, learner, console])
    try:

        def text(element_id):  # read in the page: the request box is redrawn 5 times a second
            return browser.execute_script(
                'const e = document.getElementById(arguments[0]); return e ? e.textContent : "";', element_id
            )

        browser.get(console.url)
        wait_for(lambda: text('connection') == 'connected', what='the websocket')
        # A frame of the env is shown.
        wait_for(
            lambda: browser.execute_script("return document.getElementById('frame').naturalWidth") == 500,
            what='a frame',
        )

        class Counted:
            """The learner's advice counts so far: finished episodes and the current one."""

            def __getattr__(self, kind):
                done, current = learner.learner.advice_total, learner.learner.episode_advice
                if kind == 'timeouts':
                    return done.failed['timeout'] + current.failed['timeout']
                return getattr(done, kind) + getattr(current, kind)

        totals = Counted()
        # The browser lets the page sound only after a gesture: until then the page says so. Before,
        # each request made a new audio context, silent until then, and the console warned of it.
        hidden = "return document.getElementById('sound-locked').hidden"
        assert browser.execute_script(hidden) is False
        # Shift alone (the deadman) is no gesture to the browser: before, the context was made on it,
        # stayed suspended, and the console warned 'The AudioContext was not allowed to start'.
        ActionChains(browser).key_down(Keys.SHIFT).key_up(Keys.SHIFT).perform()
        time.sleep(0.3)
        assert browser.execute_script(hidden) is False
        ActionChains(browser).send_keys(Keys.ARROW_RIGHT, Keys.ARROW_LEFT).perform()
        wait_for(lambda: browser.execute_script(hidden), what='the sound allowed after a key press')
        # Nothing in the page's console: no favicon 404 (before: one error at each load), no warning.
        assert [e['message'] for e in browser.get_log('browser') if e['level'] in ('WARNING', 'SEVERE')] == []

        def pending():
            return browser.execute_script("return document.getElementById('request').className") == 'pending'

        def keys(*sequence):
            chain = ActionChains(browser)
            for key in sequence:
                if isinstance(key, tuple):  # ('down', Keys.SHIFT) / ('up', Keys.SHIFT)
                    (chain.key_down if key[0] == 'down' else chain.key_up)(key[1])
                else:
                    chain.send_keys(key)
            chain.perform()

        # A request appears, large, with its countdown running down.
        wait_for(pending, what='a request')
        assert 'THE LEARNER ASKS FOR ADVICE' in text('request')
        first = float(text('countdown').split()[0])
        wait_for(lambda: 0 < float(text('countdown').split()[0]) < first, what='the countdown running down')
        assert first <= 3.0
        # Enter without the deadman answers nothing; with Shift held it answers.
        keys(Keys.ENTER)
        time.sleep(0.3)
        assert totals.human == 0 and pending()
        answered = re.search(r'episode \d+, step \d+', text('request')).group()
        keys(('down', Keys.SHIFT), Keys.ENTER, ('up', Keys.SHIFT))
        wait_for(lambda: totals.human >= 1, what='human advice counted')
        # The page shows the value that was given (the command held: 0 here), then its time.
        wait_for(
            lambda: re.search(r'given \[[+-]\d\.\d\d\] after \d+\.\d s', text('request')) or pending(),
            what='the answer shown with its value',
        )

        # Skip declines with its reason: pressed once the page shows the next request (one that
        # comes within a few ms of the answer can find the page still showing the answered one).
        declined = totals.declined
        shown = lambda: re.search(r'episode \d+, step \d+', text('request'))  # noqa: E731
        wait_for(lambda: pending() and shown() and shown().group() != answered, what='the next request')
        time.sleep(0.2)  # a person's reaction: a press sooner than 0.1 s after a request cannot answer it
        keys('x')
        wait_for(lambda: totals.declined == declined + 1, what='a skip')
        assert teleop.answers['skipped'] >= 1
        wait_for(lambda: SKIPPED in text('request') or pending(), what='the skip shown')

        # Silence times out.
        timeouts = totals.timeouts
        wait_for(lambda: totals.timeouts == timeouts + 1, timeout=15, what='a timeout')
        assert teleop.answers['timed_out'] >= 1

        # A gamepad through the Gamepad API: a synthetic pad, LB held (deadman), then A.
        browser.execute_script(
            """
            window.fakePad = {id: 'synthetic pad', axes: [0.5, 0, 0, 0],
              buttons: Array.from({length: 16}, () => ({pressed: false, value: 0}))};
            navigator.getGamepads = () => [window.fakePad];
            """
        )
        wait_for(lambda: 'synthetic pad' in text('gamepad'), what='the gamepad')
        human = totals.human
        wait_for(pending, what='a request for the gamepad')
        if SCREENSHOT:
            Path(SCREENSHOT).parent.mkdir(parents=True, exist_ok=True)
            browser.save_screenshot(SCREENSHOT)
        browser.execute_script('window.fakePad.buttons[4].pressed = true;')
        time.sleep(0.1)
        browser.execute_script('window.fakePad.buttons[0].pressed = true;')
        # The deadman's press answers the open request and A's press may answer the next one
        # (a loaded machine asks again within the 0.1 s), so one or two answers are right.
        wait_for(lambda: totals.human >= human + 1, what='gamepad advice')
        assert totals.human <= human + 2
        browser.execute_script('window.fakePad.buttons[0].pressed = false; window.fakePad.buttons[4].pressed = false;')

        # The controls set the learner's parameters, range-checked by the learner.
        def type_budget(text):
            budget = browser.find_element(By.ID, 'budget')
            budget.click()
            budget.send_keys(Keys.CONTROL, 'a')
            budget.send_keys(text)
            assert budget.get_attribute('value') == text
            browser.find_element(By.ID, 'set-budget').click()

        type_budget('-3')
        wait_for(
            lambda: 'refused' in text('message'),
            what=lambda: f'the refusal (page says {text("message")!r})',
        )
        assert learner.config.advising_budget == 100
        type_budget('7')
        wait_for(lambda: learner.learner.gates.advising_budget == 7, what='the budget set')
        browser.find_element(By.ID, 'pause').click()
        wait_for(lambda: learner.params['advice_enabled'] is False, what='advice paused')
        wait_for(lambda: text('pause') == 'resume advice', what='the pause shown')
        # The plots have the finished episodes.
        wait_for(lambda: learner.summaries, timeout=30, what='an episode')
        wait_for(lambda: browser.execute_script('return state.episodes.length') >= 1, what='the plot data')
    finally:
        graph.close()


def test_the_console_refuses_another_host_without_a_token_and_checks_the_token(ros_context):
    import urllib.error
    import urllib.request

    assert is_loopback('127.0.0.1') and is_loopback('::1') and is_loopback('localhost')
    assert not is_loopback('0.0.0.0') and not is_loopback('192.168.1.4')
    with pytest.raises(ValueError, match='set a token'):
        AdviceConsole(context=ros_context, parameter_overrides=params(host='0.0.0.0', port=0))
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, token='s3cret'))
    try:
        base = f'http://127.0.0.1:{console.port}/'
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(base, timeout=5)
        assert refused.value.code == 403
        with pytest.raises(urllib.error.HTTPError) as wrong:
            urllib.request.urlopen(base + '?token=guess', timeout=5)
        assert wrong.value.code == 403
        assert b'advice console' in urllib.request.urlopen(base + '?token=s3cret', timeout=5).read()
        # A websocket opened by a page of another origin is refused, even with the token.
        request = urllib.request.Request(
            base + 'ws?token=s3cret',
            headers={
                'Origin': 'http://evil.example',
                'Connection': 'Upgrade',
                'Upgrade': 'websocket',
                'Sec-WebSocket-Version': '13',
                'Sec-WebSocket-Key': 'dGhlIHNhbXBsZSBub25jZQ==',
            },
        )
        with pytest.raises(urllib.error.HTTPError) as cross:
            urllib.request.urlopen(request, timeout=5)
        assert cross.value.code == 403
    finally:
        console.destroy_node()


def test_the_pages_token_comes_from_a_file_and_never_reaches_the_graphs_log(ros_context, tmp_path):
    """Before, the token was only a parameter, which any node on the graph reads (ros2 param get),
    and the start-up line, which goes to /rosout for every node to read, carried it whole."""
    import urllib.error
    import urllib.request

    secret = 'c0ffee' * 6
    (tmp_path / 'console.token').write_text(secret + '\n')
    heard = []
    listener = rosout_listener(ros_context, heard)
    console = AdviceConsole(
        context=ros_context, parameter_overrides=params(port=0, token_file=str(tmp_path / 'console.token'))
    )
    graph = Graph(ros_context, [listener, console])
    try:
        wait_for(lambda: any('the person opens' in text for _, text in heard), what='the start-up line on /rosout')
        assert not any(secret in text for _, text in heard)
        assert any(f':{console.port}/?token=<token>, <token> as in token_file' in text for _, text in heard)
        assert console.get_parameter('token').value == ''
        base = f'http://127.0.0.1:{console.port}/'
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(base + '?token=guess', timeout=5)
        assert refused.value.code == 403
        assert b'advice console' in urllib.request.urlopen(base + f'?token={secret}', timeout=5).read()
    finally:
        graph.close()
    heard.clear()
    listener = rosout_listener(ros_context, heard)
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, token=secret))
    graph = Graph(ros_context, [listener, console])
    try:
        wait_for(lambda: any('can be read by any node' in text for _, text in heard), what='the warning')
        assert not any(secret in text for _, text in heard)
    finally:
        graph.close()
    with pytest.raises(ValueError, match='give token or token_file, not both'):
        AdviceConsole(
            context=ros_context, parameter_overrides=params(token='x' * 16, token_file=str(tmp_path / 'console.token'))
        )
    (tmp_path / 'short.token').write_text('abc')
    with pytest.raises(ValueError, match='token file .*short.token: 3 bytes; at least 16'):
        AdviceConsole(
            context=ros_context, parameter_overrides=params(host='0.0.0.0', token_file=str(tmp_path / 'short.token'))
        )


def test_the_console_checks_what_the_page_sends(ros_context):
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='Pendulum-v1'))
    try:
        assert console.take_input({'type': 'input', 'command': [0.2, 0.1]}) == 'command must be a list of 1 numbers'
        assert console.take_input({'type': 'input', 'command': ['x']}) == 'command must hold numbers'
        assert console.take_input({'type': 'input', 'command': [float('nan')]}) == 'command must be finite'
        assert console.take_input({'type': 'teleport'}) == "unknown message type 'teleport'"
        assert console.take_input({'type': 'input', 'command': [7.0], 'deadman': True}) is None
        assert console.input.command == [1.0] and console.input.deadman  # clipped to [-1, 1]
        ok, reason = console.set_learner_parameter('max_episodes', 3)
        assert not ok and 'not one of' in reason
    finally:
        console.destroy_node()


def test_the_page_is_installed_with_the_package():
    from importlib import resources

    web = resources.files('eqhrl_ros').joinpath('web')
    assert 'console.js' in web.joinpath('console.html').read_text()


def test_stop_on_the_page_holds_the_env_at_once_and_resume_lets_it_go(browser, ros_context):
    env = GymEnvNode(
        context=ros_context, parameter_overrides=params(realtime=True, rate_hz=30.0, max_episode_steps=10**6)
    )
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='Pendulum-v1'))
    import rclpy
    from std_msgs.msg import Float32MultiArray

    watcher = rclpy.create_node('watcher', context=ros_context)  # a learner's stand-in: the clock starts
    watcher.create_subscription(Float32MultiArray, 'observation', lambda msg: None, 10)
    graph = Graph(ros_context, [env, console, watcher])
    try:
        browser.get(console.url)
        wait_for(
            lambda: browser.execute_script("return document.getElementById('connection').textContent") == 'connected'
        )
        wait_for(lambda: env.steps_taken > 10, what='the env stepping')
        browser.find_element('id', 'stop').click()
        wait_for(lambda: env.stopped, timeout=5, what='the env stopped')
        frozen = env.steps_taken
        time.sleep(0.5)
        assert env.steps_taken == frozen
        wait_for(lambda: browser.execute_script("return document.body.classList.contains('stopped')"), what='banner')
        assert browser.find_element('id', 'stop').text == 'RESUME'
        assert browser.find_element('id', 'stopped-banner').is_displayed()
        browser.find_element('id', 'stop').click()
        wait_for(lambda: env.steps_taken > frozen + 5, timeout=10, what='the env stepping again')
        wait_for(lambda: browser.find_element('id', 'stop').text == 'STOP', what='the button back')
    finally:
        graph.close()


def test_the_page_counts_down_the_persons_window_and_draws_the_mapped_action(browser, ros_context):
    """LunarLander, teleop_lunar_lander.yaml's mapping (w/s drive action[0], the main engine):
    before, the bars and legend assumed a/d drove action[0], and the countdown ran to the
    learner's 5.0 s though the person's window was 4.5 s."""
    import rclpy
    from selenium.webdriver.common.action_chains import ActionChains

    from eqhrl_interfaces.msg import AdviceRequest
    from eqhrl_ros.nodes import messages

    teleop = TeleopExpertNode(
        context=ros_context,
        parameter_overrides=params(
            env_id='LunarLanderContinuous-v3',
            source='array',
            axes=[1, 0],
            scales=[1.0, 1.0],
            offsets=[0.0, 0.0],
            answer_window_s=4.5,
        ),
    )
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='LunarLanderContinuous-v3'))
    learner = rclpy.create_node('learner_stand_in', context=ros_context)
    requests = learner.create_publisher(AdviceRequest, 'learner/advice_request', messages.LATCHED_QOS)
    graph = Graph(ros_context, [teleop, console, learner])
    try:
        wait_for(lambda: console.teleop.get('axes') == [1, 0], what="teleop_expert's mapping read")
        browser.get(console.url)
        wait_for(
            lambda: browser.execute_script("return document.getElementById('key1').textContent").startswith('main')
        )
        assert browser.execute_script("return document.getElementById('key0').textContent").startswith('side')
        ActionChains(browser).send_keys('www').perform()  # command[1] = 0.75 (step 0.25): the main engine
        shown = 'return document.querySelector(\'[data-action="0"]\').textContent'
        wait_for(lambda: browser.execute_script(shown) == '+0.75', what='action[0] at +0.75')
        assert browser.execute_script('return document.querySelector(\'[data-action="1"]\').textContent') == '+0.00'
        ActionChains(browser).send_keys('s').perform()  # against the sign: to 0 first, a quick reversal
        wait_for(lambda: browser.execute_script(shown) == '+0.00', what='action[0] back at 0 in one press')
        ActionChains(browser).send_keys('ssss').perform()
        wait_for(lambda: browser.execute_script(shown) == '-1.00', what='full scale reversed in 5 presses')
        requests.publish(
            AdviceRequest(outcome=AdviceRequest.PENDING, episode=0, step=3, timeout_s=5.0, proposed_action=[0.0, 0.0])
        )
        wait_for(lambda: browser.execute_script("return document.getElementById('countdown') !== null"))
        first = float(browser.execute_script("return document.getElementById('countdown').textContent").split()[0])
        assert first <= 4.5  # the person's window, not the learner's 5.0 s
    finally:
        graph.close()


def test_the_page_says_when_advice_is_over_and_when_the_run_has_finished(browser, ros_context):
    """A stand-in learner (its parameters and its episode statistics, published by the test): the
    page's state follows each episode."""
    import rclpy

    from eqhrl_interfaces.msg import EpisodeStats

    learner = rclpy.create_node('learner', context=ros_context)
    for name, value in (
        ('mode', 'eqsac'),
        ('advice_enabled', True),
        ('advising_budget', 1),
        ('advising_budget_s', 0.0),
        ('max_episodes', 3),
    ):
        learner.declare_parameter(name, value)
    stats = learner.create_publisher(EpisodeStats, 'learner/episode_stats', 100)
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='Pendulum-v1'))
    graph = Graph(ros_context, [learner, console])
    try:
        wait_for(lambda: console.learner_params.get('max_episodes') == 3, what="the learner's parameters read")
        browser.get(console.url)
        state = "return document.getElementById('run-state').textContent"
        wait_for(
            lambda: browser.execute_script("return document.getElementById('connection').textContent") == 'connected'
        )
        assert browser.execute_script(state) == ''
        stats.publish(EpisodeStats(episode=0, length=10))
        wait_for(lambda: 'the advising budget is used up' in browser.execute_script(state), what='advice over')
        stats.publish(EpisodeStats(episode=1, length=10))
        stats.publish(EpisodeStats(episode=2, length=10))
        wait_for(lambda: 'the run has finished (3 episodes)' in browser.execute_script(state), what='run finished')
    finally:
        graph.close()


def test_the_page_runs_the_persons_budget_in_seconds_down_request_by_request(browser, ros_context):
    """A stand-in learner with a budget of 60 of the person's seconds: each answered request takes
    its reaction time off the seconds left at once, before its episode's statistics come."""
    import rclpy

    from eqhrl_interfaces.msg import AdviceRequest, EpisodeStats
    from eqhrl_ros.nodes import messages

    learner = rclpy.create_node('learner', context=ros_context)
    for name, value in (
        ('mode', 'eqsac'),
        ('advice_enabled', True),
        ('advising_budget', 30),
        ('advising_budget_s', 60.0),
        ('max_episodes', 0),
    ):
        learner.declare_parameter(name, value)
    stats = learner.create_publisher(EpisodeStats, 'learner/episode_stats', 100)
    requests = learner.create_publisher(AdviceRequest, 'learner/advice_request', messages.LATCHED_QOS)
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='Pendulum-v1'))
    graph = Graph(ros_context, [learner, console])
    person = "return document.getElementById('person').textContent"
    try:
        wait_for(lambda: console.learner_params.get('advising_budget_s') == 60.0, what="the learner's budget read")
        browser.get(console.url)
        wait_for(lambda: '60.0 s left' in browser.execute_script(person), what='the whole budget shown')
        for step, seconds in ((4, 2.5), (9, 1.5)):
            requests.publish(
                AdviceRequest(
                    outcome=AdviceRequest.GIVEN, episode=0, step=step, timeout_s=5.0, human=True,
                    response_time_s=seconds, proposed_action=[0.0], given_action=[1.0],
                )
            )  # fmt: skip
            if step == 4:
                wait_for(lambda: '57.5 s left' in browser.execute_script(person), what='2.5 s spent on the first')
        wait_for(lambda: '56.0 s left' in browser.execute_script(person), what='4.0 s spent within the episode')
        # The episode's statistics now hold those seconds: counted once, not twice.
        stats.publish(EpisodeStats(episode=0, length=10, human_time_s=4.0, human_time_total_s=4.0))
        wait_for(lambda: 'your time: 4.0 s over 1 episodes' in browser.execute_script(person), what='the episode')
        assert '56.0 s left' in browser.execute_script(person)
    finally:
        graph.close()


def test_an_experts_reason_is_shown_as_text_and_never_runs_on_the_page(browser, ros_context):
    """The page lists the requests that ended, with a declining expert's reason: another node's
    words. Markup in them is shown as text, never made into elements (no script of theirs runs)."""
    import rclpy

    from eqhrl_interfaces.msg import AdviceRequest
    from eqhrl_ros.nodes import messages

    learner = rclpy.create_node('learner', context=ros_context)
    requests = learner.create_publisher(AdviceRequest, 'learner/advice_request', messages.LATCHED_QOS)
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='Pendulum-v1'))
    graph = Graph(ros_context, [learner, console])
    reason = '<img src=x onerror="window.ran = 1">no'
    try:
        browser.get(console.url)
        wait_for(
            lambda: browser.execute_script("return document.getElementById('connection').textContent") == 'connected'
        )
        requests.publish(AdviceRequest(outcome=AdviceRequest.DECLINED, episode=0, step=3, detail=reason))
        shown_as_text(browser, reason, 'recent', 'request')
    finally:
        graph.close()


def test_an_envs_action_labels_are_shown_as_text_and_never_run_on_the_page(browser, ros_context):
    """The bars are labelled with the env's action_labels: its env_info, another node's words.
    Before, a label was put into the page as markup, so an env announcing
    '<img src=x onerror=...>' ran its script in the person's page (which holds STOP and the wheel)."""
    import rclpy

    from eqhrl_interfaces.msg import EnvInfo
    from eqhrl_ros.nodes.env_info import ENV_INFO_QOS

    label = '<img src=x onerror="window.ran = 1">force'
    env = rclpy.create_node('env_stand_in', context=ros_context)
    announce = env.create_publisher(EnvInfo, 'env_info', ENV_INFO_QOS)
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_node='/env_stand_in'))
    graph = Graph(ros_context, [env, console])
    try:
        announce.publish(
            EnvInfo(
                publisher='/env_stand_in',
                name='stand_in',
                observation_size=2,
                action_size=1,
                action_labels=[label],
                action_low=[-1.0],
                action_high=[1.0],
            )
        )
        wait_for(lambda: console.spec is not None, what="the env's env_info taken")
        browser.get(console.url)
        shown_as_text(browser, label, 'bars')
    finally:
        graph.close()


def test_a_learners_message_with_numbers_out_of_meaning_is_dropped_and_the_page_goes_on(browser, ros_context):
    """A NaN return or a NaN wait in the learner's messages: before, the console sent them as JSON's
    non-standard NaN, the page could not parse any state after that, and it froze (no request, no
    episode) for as long as the message was kept: the latched request, or 500 episodes."""
    import rclpy

    from eqhrl_interfaces.msg import AdviceRequest, EpisodeStats
    from eqhrl_ros.nodes import messages

    learner = rclpy.create_node('learner', context=ros_context)
    requests = learner.create_publisher(AdviceRequest, 'learner/advice_request', messages.LATCHED_QOS)
    stats = learner.create_publisher(EpisodeStats, 'learner/episode_stats', 100)
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='Pendulum-v1'))
    graph = Graph(ros_context, [learner, console])
    person = "return document.getElementById('person').textContent"
    try:
        browser.get(console.url)
        wait_for(lambda: 'over 0 episodes' in browser.execute_script(person), what='the page up')

        # One at a time: the request topic is latched with depth 1 (a newer request replaces one not yet read).
        def taken(step):  # dropped, or (without the checks) shown
            return lambda: (
                getattr(console, 'dropped', 0) >= step or len(console.episodes) + bool(console.request) >= step
            )

        stats.publish(EpisodeStats(episode=0, length=10, episode_return=math.nan))
        wait_for(taken(1))
        requests.publish(AdviceRequest(outcome=AdviceRequest.PENDING, episode=0, step=3, timeout_s=math.inf))
        wait_for(taken(2))
        requests.publish(
            AdviceRequest(outcome=AdviceRequest.PENDING, episode=1, step=4, timeout_s=5.0, proposed_action=[math.nan])
        )
        wait_for(lambda: getattr(console, 'dropped', 0) >= 3 or (console.request or {}).get('step') == 4)
        stats.publish(EpisodeStats(episode=1, length=10, episode_return=-3.0))
        requests.publish(
            AdviceRequest(outcome=AdviceRequest.PENDING, episode=2, step=7, timeout_s=5.0, proposed_action=[0.5])
        )
        request = "return document.getElementById('request').textContent"
        wait_for(
            lambda: 'episode 2, step 7' in browser.execute_script(request), what=lambda: browser.execute_script(request)
        )
        assert 'over 1 episodes' in browser.execute_script(person)
        assert console.dropped == 3
    finally:
        graph.close()


def test_no_other_site_can_frame_the_page(browser, ros_context, tmp_path):
    """Before, a site open in the person's browser could frame the page (the frame's websocket came
    from the console's own origin, so it was let in) and lay a decoy over STOP or RESUME."""
    import functools
    import http.server

    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='Pendulum-v1'))
    graph = Graph(ros_context, [console])
    (tmp_path / 'decoy.html').write_text(f'<iframe src="{console.url}" width="900" height="700"></iframe>')
    quiet = type('Quiet', (http.server.SimpleHTTPRequestHandler,), {'log_message': lambda *args: None})
    site = http.server.ThreadingHTTPServer(('127.0.0.1', 0), functools.partial(quiet, directory=str(tmp_path)))
    threading.Thread(target=site.serve_forever, daemon=True).start()
    try:
        # Another site: another origin (localhost, not the console's 127.0.0.1, and another port).
        browser.get(f'http://localhost:{site.server_address[1]}/decoy.html')

        def refused():
            return any('frame-ancestors' in entry['message'] for entry in browser.get_log('browser'))

        wait_for(refused, what="the browser's refusal to frame the page")
        assert console.pages == 0  # no page of the frame ever connected
        browser.get(console.url)  # opened as itself, it works under the same policy
        wait_for(lambda: console.pages == 1, what='the page connected')
        assert browser.execute_script("return document.getElementById('env').textContent") == 'env: Pendulum-v1'
    finally:
        site.shutdown()
        graph.close()


def test_the_page_shows_the_frames_a_camera_learner_asked_about_pixel_for_pixel(browser, ros_context):
    """A camera learner's request carries the stack it asks about (learner/advice_request frames):
    the page shows it beside the env's rendering, at the learner's size and drawn in whole pixels,
    oldest left, each pixel as sent; frames that cannot be one stack change nothing on the page."""
    import numpy as np
    import rclpy

    from eqhrl_interfaces.msg import AdviceRequest
    from eqhrl_ros.nodes import messages
    from eqhrl_ros.nodes.frame_msgs import image_msg, stack_msgs

    learner = rclpy.create_node('learner', context=ros_context)
    requests = learner.create_publisher(AdviceRequest, 'learner/advice_request', messages.LATCHED_QOS)
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='Pendulum-v1'))
    graph = Graph(ros_context, [learner, console])
    stack = np.zeros((2, 20, 24, 3), np.uint8)
    stack[0, :, :] = (200, 10, 10)  # the older frame red, the newer blue with a green corner
    stack[1, :, :] = (10, 10, 200)
    stack[1, :5, :5] = (10, 220, 10)
    asked = "const a = document.getElementById('asked'); return [a.naturalWidth, a.naturalHeight, a.dataset.frames]"
    caption = "return document.getElementById('asked-caption').textContent"
    pixels = """const a = document.getElementById('asked'); const c = document.createElement('canvas');
        c.width = a.naturalWidth; c.height = a.naturalHeight; const g = c.getContext('2d');
        g.drawImage(a, 0, 0);
        return [[5, 10], [30, 10], [25, 2]].map(([x, y]) => Array.from(g.getImageData(x, y, 1, 1).data.slice(0, 3)));"""
    try:
        browser.get(console.url)
        wait_for(
            lambda: browser.execute_script("return document.getElementById('connection').textContent") == 'connected'
        )
        assert browser.execute_script("return document.getElementById('asked-view').hidden") is True
        pending = AdviceRequest(
            outcome=AdviceRequest.PENDING, episode=3, step=17, timeout_s=5.0, frames=stack_msgs(stack)
        )
        requests.publish(pending)
        wait_for(lambda: browser.execute_script(asked)[:2] == [48, 20], what='the stack shown at its size')
        assert browser.execute_script(pixels) == [[200, 10, 10], [10, 10, 200], [10, 220, 10]]
        shown = re.fullmatch(
            r'what the learner saw when it asked \(episode 3, step 17\): 2 frames of 24x20 rgb8, oldest left, '
            r'as it reads them, drawn (\d+)x',
            browser.execute_script(caption),
        )
        scale = int(shown.group(1))  # a whole number of screen pixels a pixel, as large as the page allows
        width = browser.execute_script("return document.getElementById('asked').getBoundingClientRect().width")
        assert 1 <= scale <= 12 and width == 48 * scale
        # The same request resolved: its frames are not sent again.
        requests.publish(AdviceRequest(outcome=AdviceRequest.GIVEN, episode=3, step=17, frames=stack_msgs(stack)))
        wait_for(lambda: console.request and console.request['outcome'] == 'given', what='the answer')
        # Another node's frames that cannot be one stack: refused, the page keeps what it showed.
        bad = [image_msg(stack[0], ''), image_msg(stack[1, :10], '')]
        requests.publish(AdviceRequest(outcome=AdviceRequest.PENDING, episode=3, step=40, frames=bad))
        wait_for(lambda: console.request and console.request['step'] == 40, what='the bad request')
        time.sleep(0.3)
        assert browser.execute_script(asked) == [48, 20, '1'] and console.asked.step == 17
    finally:
        graph.close()


def test_the_page_shows_the_learners_camera_live_at_its_size(browser, ros_context):
    """The page follows the camera the learner reads (its camera parameters, the size from
    env_info) and shows its newest frame, losslessly, at the learner's size; while a stranger
    publishes on that topic too, its frames are refused, as the learner refuses them."""
    import numpy as np
    import rclpy
    from sensor_msgs.msg import Image

    from eqhrl_ros.nodes.frame_msgs import frame_of, image_msg

    camera = dict(camera='cam', camera_height=20, camera_width=24, camera_encoding='rgb8')
    env = GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=20, **camera))
    learner = rclpy.create_node('learner', context=ros_context)
    for name, value in (('camera', 'cam'), ('camera_transport', 'raw'), ('camera_publisher', '')):
        learner.declare_parameter(name, value)
    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0))
    graph = Graph(ros_context, [env, learner, console])
    shown = "const a = document.getElementById('camera'); return [a.naturalWidth, a.naturalHeight]"
    caption = "return document.getElementById('camera-caption').textContent"
    pixel = """const a = document.getElementById('camera'); const c = document.createElement('canvas');
        c.width = a.naturalWidth; c.height = a.naturalHeight; const g = c.getContext('2d'); g.drawImage(a, 0, 0);
        return Array.from(g.getImageData(arguments[0], arguments[1], 1, 1).data.slice(0, 3));"""
    try:
        browser.get(console.url)
        wait_for(lambda: browser.execute_script(shown) == [24, 20], what="the learner's camera at its size")
        assert re.fullmatch(
            r"what the learner sees now: camera 'cam' on /cam/image_raw, 24x20 rgb8, drawn \d+x",
            browser.execute_script(caption),
        )
        frame = frame_of(env._last_frame)  # what the env sent, pixel for pixel
        for x, y in ((0, 0), (12, 10), (23, 19)):
            assert browser.execute_script(pixel, x, y) == frame[y, x].tolist()
        # A stranger on the camera's topic: no frame is taken from it (nor from the env meanwhile).
        stranger = rclpy.create_node('stranger', context=ros_context)
        graph.executor.add_node(stranger)
        graph.nodes.append(stranger)
        fake = stranger.create_publisher(Image, '/cam/image_raw', 10)
        wait_for(lambda: console.count_publishers('/cam/image_raw') == 2, what='the stranger on the graph')
        time.sleep(0.6)  # the graph is judged at most every 0.5 s
        kept = console.learner_camera.number
        for _ in range(5):
            fake.publish(image_msg(np.zeros((20, 24, 3), np.uint8), 'cam'))
        wait_for(lambda: console.learner_camera.refused >= 5, what='the stranger refused')
        assert console.learner_camera.number == kept
        wait_for(lambda: 'frames refused' in browser.execute_script(caption), what='the refusals said on the page')
    finally:
        graph.close()


def test_a_port_taken_by_another_page_is_refused_with_how_to_give_each_its_own(ros_context):
    """From outside: a second robot's page (train.launch.py included twice, expert:=teleop) could
    only say `address already in use`."""
    taken = socket.socket()
    taken.bind(('127.0.0.1', 0))
    taken.listen()
    try:
        port = taken.getsockname()[1]
        with pytest.raises(start_up_errors(), match=r'port:=8081, or port:=0 for any free one\)$') as refused:
            AdviceConsole(context=ros_context, parameter_overrides=params(port=port, env_id='Pendulum-v1'))
        assert f'cannot serve on 127.0.0.1:{port}' in str(refused.value)
    finally:
        taken.close()


def test_a_stopping_console_tells_each_page_why_before_its_socket_closes(ros_context):
    """The page shows "the console has stopped (reason)" from the close frame's reason, which
    aiohttp 3.9 (Ubuntu 24.04's python3-aiohttp) loses: its own end of the handler closes first,
    with code 1000 and no reason, and the page said the console was merely not reachable."""
    import asyncio

    import aiohttp

    console = AdviceConsole(context=ros_context, parameter_overrides=params(port=0, env_id='Pendulum-v1'))
    heard, connected = [], threading.Event()

    async def page():
        async with aiohttp.ClientSession() as session:
            async with session.ws_connect(f'http://127.0.0.1:{console.port}/ws') as socket:
                connected.set()
                async for message in socket:
                    if message.type == aiohttp.WSMsgType.TEXT:
                        heard.append(message.json())
                heard.append({'closed': socket.close_code})

    reader = threading.Thread(target=asyncio.run, args=(page(),), daemon=True)
    try:
        reader.start()
        assert connected.wait(10)
        console.server.stop()
        reader.join(timeout=10)
        assert not reader.is_alive() and heard[-1]['closed'] is not None, heard
        assert heard[-2] == {'type': 'stopping', 'reason': 'advice_console is stopping'}, heard
    finally:
        console.destroy_node()
