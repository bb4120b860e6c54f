"""A person as the expert: teleop mapping, the teleop_expert node, frames, and keyboard_teleop in tmux."""

import csv
import dataclasses
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import Twist
from rclpy.impl.rcutils_logger import RcutilsLogger
from sensor_msgs.msg import Image, Joy
from std_msgs.msg import Float32MultiArray

from eqhrl_interfaces.msg import AdviceRequest as AdviceRequestMsg
from eqhrl_interfaces.srv import Advise
from eqhrl_ros.core.data.advice import AdviceRequest
from eqhrl_ros.core.experts.teleop import TeleopExpert, array_command, joy_command, twist_command
from eqhrl_ros.nodes import advise_msgs, messages
from eqhrl_ros.nodes.gym_env_node import GymEnvNode
from eqhrl_ros.nodes.learner_node import LearnerNode
from eqhrl_ros.nodes.teleop_expert_node import TeleopExpertNode

from ros_helpers import params, small_learner_params


def request(low=(-2.0,), high=(2.0,)):
    n = len(low)
    return AdviceRequest(
        np.zeros(3, np.float32),
        np.zeros(n, np.float32),
        np.array(low, np.float32),
        np.array(high, np.float32),
        1.0,
        -1.0,
        0,
        0,
    )


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


# ------------------------------------------------------------------ core mapping


def test_joy_mapping_scales_axes_and_requires_the_deadman():
    held = joy_command(
        [0.1, -0.5, 0.9],
        [0, 1],
        axis_indices=[1, 2],
        scales=[2.0, -1.0],
        offsets=[0.0, 0.5],
        require_enable_button=True,
        enable_button=1,
    )
    assert held.enabled and held.values.tolist() == pytest.approx([-1.0, -0.4])
    released = joy_command([0.1, -0.5, 0.9], [0, 0], [1], [1.0], [0.0], True, 1)
    assert not released.enabled and 'button 1 is not held' in released.disabled_reason
    assert joy_command([0.3], [], [0, 7], [1.0, 1.0], [0.0, 0.0], False).values.tolist() == pytest.approx([0.3, 0.0])


def test_twist_and_array_mappings():
    fields = {'linear.x': 0.5, 'angular.z': -1.0}
    command = twist_command(fields.get, ['linear.x', 'angular.z'], [1.0, -1.0], [0.0, 0.0])
    assert command.enabled and command.values.tolist() == [0.5, 1.0]
    assert array_command({'command': [0.25, -0.5]}, [1, 0], [2.0, 1.0], [0.0, 0.0]).values.tolist() == [-1.0, 0.25]
    with pytest.raises(ValueError, match='indices'):
        array_command({'command': [0.1]}, [0, 1], [1.0, 1.0], [0.0, 0.0])
    # The labelled message keyboard_teleop and advice_console publish: deadman and buttons.
    released = array_command(
        messages.read_fields(messages.command_msg([0.5], enabled=False, answer=True, skip=False)), [0], [1.0], [0.0]
    )
    assert not released.enabled and released.answer and not released.skip and released.values.tolist() == [0.5]


def test_teleop_expert_declines_with_reasons_and_clips():
    clock = FakeClock()
    expert = TeleopExpert(stale_after_s=0.5, name='person', clock=clock)
    assert 'no teleop command' in expert(request()).reason
    expert.update(array_command({'command': [0.9]}, [0], [4.0], [0.0]))  # 3.6, beyond the torque limit
    advice = expert(request())
    assert advice.advised and advice.human and advice.action.tolist() == [2.0]
    clock.now += 0.6
    assert not expert(request()).advised and 'old' in expert(request()).reason
    expert.update(joy_command([0.5], [0], [0], [1.0], [0.0], True, 0))
    assert 'not held' in expert(request()).reason
    expert.update(array_command({'command': [0.1, 0.2]}, [0, 1], [1.0, 1.0], [0.0, 0.0]))
    assert 'has 2 values' in expert(request()).reason


# ------------------------------------------------------------------ the node


def call_advise(harness, client, low=(-2.0,), high=(2.0,), seal=None):
    """teleop_expert's answer to a request (signed with ``seal``, an advise_msgs.request_seal)."""
    assert harness.spin_until(client.service_is_ready)
    request = Advise.Request(
        observation=[0.0, 0.0, 0.0], proposed_action=[0.0] * len(low), action_low=list(low), action_high=list(high)
    )
    future = client.call_async(advise_msgs.sign_request(request, seal))
    assert harness.spin_until(future.done)
    return future.result()


def test_teleop_expert_node_follows_joy_with_deadman_and_staleness(harness, ros_context, monkeypatch):
    warned = []
    monkeypatch.setattr(RcutilsLogger, 'warning', lambda logger, line, **kw: warned.append(line))
    harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(
                source='joy',
                axes=[1],
                scales=[3.0],
                offsets=[0.0],
                enable_button=2,
                stale_after_s=0.3,
                answer_mode='instant',
            ),
        )
    )
    probe = harness.add(rclpy.create_node('joy_probe', context=ros_context))
    joy_pub = probe.create_publisher(Joy, 'joy', 10)
    client = probe.create_client(Advise, 'advise')

    assert call_advise(harness, client).reason == 'no teleop command received yet'
    assert harness.spin_until(lambda: joy_pub.get_subscription_count() > 0)

    def send(axes, buttons):
        joy_pub.publish(Joy(axes=axes, buttons=buttons))
        harness.spin_until(lambda: False, timeout=0.1)

    send([0.0, 0.4], [0, 0, 1])
    response = call_advise(harness, client)
    assert response.advised and response.human and list(response.action) == pytest.approx([1.2])
    assert response.expert_name == '/teleop_expert'
    send([0.0, -0.9], [0, 0, 1])  # -2.7: clipped to the bound
    assert list(call_advise(harness, client).action) == pytest.approx([-2.0])
    send([0.0, 0.4], [0, 0, 0])  # deadman released
    response = call_advise(harness, client)
    assert not response.advised and 'button 2 is not held' in response.reason
    send([0.0, 0.4], [0, 0, 1])
    harness.spin_until(lambda: False, timeout=0.5)  # no new command: stale
    response = call_advise(harness, client)
    assert not response.advised and 'old' in response.reason
    assert not [line for line in warned if "'joy' has" in line]  # the mapping fits this joystick
    # A joystick with fewer axes and buttons than mapped: before, its axis read as 0 and its deadman
    # was never held, and the person saw nothing move, without a word of why.
    send([0.4], [1])
    said = "'joy' has 1 axes and 1 buttons, but axes[0] is 1, enable_button is 2, answer_button is 1, skip_button is 2"
    assert any(line.startswith(said) for line in warned), warned


def test_teleop_expert_node_follows_twist(harness, ros_context):
    harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(
                source='twist',
                twist_fields=['linear.x', 'angular.z'],
                axes=[0, 1],
                scales=[1.0, -1.0],
                offsets=[0.0, 0.0],
                answer_mode='instant',
            ),
        )
    )
    probe = harness.add(rclpy.create_node('twist_probe', context=ros_context))
    twist_pub = probe.create_publisher(Twist, 'cmd_vel', 10)
    client = probe.create_client(Advise, 'advise')
    assert harness.spin_until(lambda: twist_pub.get_subscription_count() > 0)
    twist = Twist()
    twist.linear.x, twist.angular.z = 0.5, 0.8
    twist_pub.publish(twist)
    harness.spin_until(lambda: False, timeout=0.1)
    response = call_advise(harness, client, low=(-1.0, -1.0), high=(1.0, 1.0))
    assert response.advised and list(response.action) == pytest.approx([0.5, -0.8])


def test_teleop_mapping_of_the_wrong_length_is_refused(ros_context):
    with pytest.raises(ValueError, match="'axes' has 2 values"):
        TeleopExpertNode(context=ros_context, parameter_overrides=params(source='joy', axes=[0, 1], scales=[1.0]))
    # From outside, `-p axes:=[]`: rcl leaves an empty array unset, and the node died in a TypeError.
    with pytest.raises(ValueError, match="^parameter 'axes' has 0 values, 'scales' has 1$"):
        TeleopExpertNode(context=ros_context, cli_args=['--ros-args', '-p', 'source:=joy', '-p', 'axes:=[]'])
    # Before, taken: every answer was NaN (refused by the learner), or the axis read as 0.
    for given, refusal in [
        ('scales:=[.nan]', r"^parameters 'scales' \[nan\] and 'offsets' \[0.0\] must be finite$"),
        ('offsets:=[.inf]', r"^parameters 'scales' \[1.0\] and 'offsets' \[inf\] must be finite$"),
        ('axes:=[-7]', r"^parameter 'axes' \[-7\] holds a negative index$"),
    ]:
        with pytest.raises(ValueError, match=refusal):
            TeleopExpertNode(context=ros_context, cli_args=['--ros-args', '-p', 'source:=joy', '-p', given])


def test_env_publishes_frames_of_the_right_size_and_encoding(harness, ros_context):
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(publish_images=True, image_rate_hz=20.0)))
    probe = harness.add(rclpy.create_node('image_probe', context=ros_context))
    frames = []
    probe.create_subscription(Image, 'gym_env/image', frames.append, 5)
    assert harness.spin_until(lambda: len(frames) >= 2)
    frame = frames[-1]
    assert frame.encoding == 'rgb8' and (frame.height, frame.width) == (500, 500)
    assert frame.step == 500 * 3 and len(frame.data) == 500 * 500 * 3
    pixels = np.frombuffer(bytes(frame.data), np.uint8)
    assert pixels.min() < pixels.max()  # a picture, not a blank buffer


def test_advice_from_a_person_is_marked_in_stats_and_csv(harness, ros_context, tmp_path):
    harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(
                source='array', axes=[0], scales=[2.0], offsets=[0.0], stale_after_s=5.0, answer_mode='instant'
            ),
        )
    )
    probe = harness.add(rclpy.create_node('keyboard_teleop', context=ros_context))  # a driver as a person uses it
    command_pub = probe.create_publisher(Float32MultiArray, 'teleop_command', 10)
    requests = []
    from eqhrl_ros.nodes.messages import LATCHED_QOS as LATCHED

    probe.create_subscription(AdviceRequestMsg, 'learner/advice_request', requests.append, LATCHED)
    assert harness.spin_until(lambda: command_pub.get_subscription_count() > 0)
    command_pub.publish(messages.build([('command', [0.5])]))
    harness.add(GymEnvNode(context=ros_context, parameter_overrides=params(max_episode_steps=25)))
    learner = harness.add(
        LearnerNode(
            context=ros_context, parameter_overrides=small_learner_params(tmp_path, mode='qasac', max_episodes=2)
        )
    )
    assert harness.spin_until(lambda: learner.done, timeout=60)
    totals = learner.learner.advice_total
    assert totals.given > 0 and totals.human == totals.given
    with open(tmp_path / 'episodes.csv', newline='') as f:
        rows = list(csv.DictReader(f))
    assert sum(int(r['advice_human']) for r in rows) == totals.human
    outcomes = [m.outcome for m in requests]
    assert AdviceRequestMsg.PENDING in outcomes and AdviceRequestMsg.GIVEN in outcomes


# ------------------------------------------------------------------ keyboard_teleop, for real, in tmux


class Tmux:
    def __init__(self, name):
        if shutil.which('tmux') is None:
            pytest.fail('tmux is needed for this test: apt-get install tmux')
        self.base = ['tmux', '-L', name]  # a private server: inherits this test's ROS domain
        subprocess.run(
            self.base + ['new-session', '-d', '-s', 'kb', '-x', '110', '-y', '20', 'bash --norc --noprofile'],
            check=True,
            env=dict(os.environ, PS1='$ '),
        )

    def send(self, *keys):
        subprocess.run(self.base + ['send-keys', '-t', 'kb', *keys], check=True)

    def screen(self) -> str:
        return subprocess.run(
            self.base + ['capture-pane', '-p', '-t', 'kb'], check=True, capture_output=True, text=True
        ).stdout

    def wait_for(self, text, timeout=20.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.screen():
                return True
            time.sleep(0.1)
        return False

    def wait_for_line(self, pattern, timeout=20.0) -> bool:
        """A whole screen line matching the regular expression ``pattern``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if re.search(f'^{pattern}$', self.screen(), re.M):
                return True
            time.sleep(0.1)
        return False

    def running(self) -> str:
        return subprocess.run(
            self.base + ['display-message', '-p', '-t', 'kb', '#{pane_current_command}'],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()

    def close(self):
        subprocess.run(self.base + ['kill-server'], capture_output=True)


@pytest.mark.slow
def test_keyboard_teleop_in_a_real_terminal(harness, ros_context):
    probe = harness.add(rclpy.create_node('keyboard_probe', context=ros_context))
    commands = []
    probe.create_subscription(Float32MultiArray, 'teleop_command', commands.append, 50)
    from eqhrl_ros.nodes.messages import LATCHED_QOS as LATCHED

    request_pub = probe.create_publisher(AdviceRequestMsg, 'learner/advice_request', LATCHED)
    ask = AdviceRequest(
        np.zeros(3, np.float32),
        np.zeros(2, np.float32),
        -np.ones(2, np.float32),
        np.ones(2, np.float32),
        2.0,
        -1.0,
        3,
        41,
    )
    request_pub.publish(messages.advice_request_msg('pending', ask, 2.0))

    tmux = Tmux(f'eqhrl_test_{os.getpid()}')
    try:
        tmux.send(f'{Path(sys.prefix) / "bin" / "keyboard_teleop"} --ros-args -p dimensions:=2', 'Enter')
        assert tmux.wait_for('q : quit'), tmux.screen()
        assert tmux.wait_for('THE LEARNER ASKS FOR ADVICE: episode 3, step 41'), tmux.screen()

        def latest():
            harness.spin_until(lambda: False, timeout=0.3)
            return list(commands[-1].data) if commands else None

        def command():
            return messages.read_fields(commands[-1])['command'] if commands else None

        tmux.send('d', 'd', 'w')
        assert harness.spin_until(lambda: command() == [0.5, 0.25])
        assert tmux.wait_for('command: [+0.50, +0.25]'), tmux.screen()
        tmux.send('a', 'a', 'a', 'a', 'a', 'a')  # to 0 first (against the sign), then steps, clipped at -1
        assert harness.spin_until(lambda: command() == [-1.0, 0.25])
        tmux.send('d')  # a reversal starts at 0: full scale reverses in 1 + 1/step presses
        assert harness.spin_until(lambda: command() == [0.0, 0.25])
        tmux.send('d', 'd', 'd', 'd')
        assert harness.spin_until(lambda: command() == [1.0, 0.25])
        tmux.send('Space')
        assert harness.spin_until(lambda: command() == [0.0, 0.0])
        # Enter and x are presses of the answer and skip buttons: held in one message.
        count = len(commands)
        tmux.send('Enter')
        assert harness.spin_until(lambda: any(messages.read_fields(m)['answer'] == [1.0] for m in commands[count:]))
        tmux.send('x')
        assert harness.spin_until(lambda: any(messages.read_fields(m)['skip'] == [1.0] for m in commands[count:]))
        assert messages.read_fields(commands[-1])['enabled'] == [1.0]
        tmux.send('p')
        assert tmux.wait_for('PAUSED'), tmux.screen()
        latest()  # what was sent before the pause arrives
        count = len(commands)
        assert latest() is not None and len(commands) - count <= 1  # nothing sent while paused

        request_pub.publish(messages.advice_request_msg('given', ask, 2.0, human=True, response_time_s=1.25))
        assert tmux.wait_for('no request pending (last one: given after 1.2 s)'), tmux.screen()

        # Asked for the wheel: t is the deadman (a toggle: a terminal hears no key releases).
        tmux.send('p')  # sending again
        request_pub.publish(messages.advice_request_msg('pending', ask, 4.0, wheel=True))
        assert tmux.wait_for('TAKE THE WHEEL: press t'), tmux.screen()

        def enabled():
            return messages.read_fields(commands[-1])['enabled'] if commands else None

        assert harness.spin_until(lambda: enabled() == [0.0])  # not held until t
        tmux.send('t')
        assert harness.spin_until(lambda: enabled() == [1.0])
        assert tmux.wait_for('YOU DRIVE (asked)'), tmux.screen()
        tmux.send('t')  # handed back
        assert harness.spin_until(lambda: enabled() == [0.0])
        tmux.send('t')
        assert harness.spin_until(lambda: enabled() == [1.0])
        request_pub.publish(messages.advice_request_msg('taken', ask, 4.0, wheel=True))
        tmux.send('t')  # handed back: until the learner says how the request ended, it drives again
        assert tmux.wait_for('you handed the wheel back: the learner drives'), tmux.screen()
        assert 'TAKE THE WHEEL' not in tmux.screen()  # before: the alert came back, '0.0 s left'
        tmux.send('t')  # each key's effect is waited for on the screen: a command sent before it may still arrive
        assert tmux.wait_for('YOU DRIVE (asked)'), tmux.screen()
        request_pub.publish(messages.advice_request_msg('given', ask, 4.0, 'agreed', human=True, wheel=True))
        assert tmux.wait_for('last one: given'), tmux.screen()
        assert harness.spin_until(lambda: enabled() == [0.0])  # the learner took it back: released here too
        # t pressed with nothing asked: said as it is, and a request that comes then is not taken by it
        # (the learner waits for a press): before, the screen said YOU DRIVE while the learner drove.
        tmux.send('t')
        assert tmux.wait_for('t held (the deadman): unasked'), tmux.screen()
        later = dataclasses.replace(ask, step=60)
        request_pub.publish(messages.advice_request_msg('pending', later, 4.0, wheel=True))
        assert tmux.wait_for('TAKE THE WHEEL: press t'), tmux.screen()
        assert harness.spin_until(lambda: enabled() == [0.0]) and 'YOU DRIVE' not in tmux.screen()

        tmux.send('q')
        deadline = time.monotonic() + 20
        while tmux.running() != 'bash' and time.monotonic() < deadline:
            time.sleep(0.1)
        assert tmux.running() == 'bash', tmux.screen()  # keyboard_teleop exited
        # The typed line holds 'DONE""' and '-icanon'; only the output holds 'FLAGS: ... DONE'.
        tmux.send(
            'clear; echo FLAGS: $(stty -a | tr " " "\\n" | grep -x -e icanon -e -icanon -e echo -e -echo) DONE""',
            'Enter',
        )
        assert tmux.wait_for_line(r'FLAGS: .* DONE'), tmux.screen()
        settings = re.search(r'^FLAGS: (.*) DONE$', tmux.screen(), re.M).group(1).split()
        assert 'icanon' in settings and 'echo' in settings, tmux.screen()  # the terminal is restored
        assert '-icanon' not in settings and '-echo' not in settings
    finally:
        tmux.close()


@pytest.mark.parametrize('value', [float('nan'), float('inf'), 1e30, 1.5])
def test_commands_that_cannot_be_a_persons_are_refused(value):
    with pytest.raises(ValueError, match=r'non-finite|outside \[-1, 1\]'):
        array_command({'command': [value]}, [0], [2.0], [0.0])
    with pytest.raises(ValueError, match=r'non-finite|outside \[-1, 1\]'):
        joy_command([value], [1], [0], [2.0], [0.0])
    if not np.isfinite(value):
        with pytest.raises(ValueError, match='non-finite'):
            twist_command(lambda field: value, ['angular.z'], [1.0], [0.0])


def test_a_second_command_publisher_answers_nothing_for_the_person(harness, ros_context):
    """The console publishes the person's command; a rogue node publishes on teleop_command too.
    Before, the rogue answered 8 of 8 requests as the person. Now every command is refused while
    two nodes publish, and with command_publisher set, a rogue alone is refused as well."""
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(
                source='array',
                axes=[0],
                scales=[2.0],
                offsets=[0.0],
                answer_mode='instant',
                stale_after_s=5.0,
                command_publisher='/advice_console',
            ),
        )
    )
    console = harness.add(rclpy.create_node('advice_console', context=ros_context))
    rogue = harness.add(rclpy.create_node('rogue', context=ros_context))
    console_pub = console.create_publisher(Float32MultiArray, 'teleop_command', 10)
    client = console.create_client(Advise, 'advise')

    def command(value):
        return messages.command_msg([value], True, False, False)

    assert harness.spin_until(lambda: console_pub.get_subscription_count() > 0)
    console_pub.publish(command(0.5))
    harness.spin_until(lambda: False, timeout=0.3)
    response = call_advise(harness, client)
    assert response.advised and list(response.action) == pytest.approx([1.0])

    rogue_pub = rogue.create_publisher(Float32MultiArray, 'teleop_command', 10)
    assert harness.spin_until(lambda: len(teleop.get_publishers_info_by_topic('/teleop_command')) == 2, timeout=10)
    harness.spin_until(lambda: False, timeout=0.6)  # past the graph cache
    rejected = teleop.rejected_commands
    for _ in range(5):
        rogue_pub.publish(command(-1.0))
        harness.spin_until(lambda: False, timeout=0.1)
    assert teleop.rejected_commands >= rejected + 5
    response = call_advise(harness, client)
    assert not (response.advised and list(response.action) == pytest.approx([-2.0]))

    console.destroy_node()  # the console goes; the rogue alone is not the configured publisher
    harness.nodes.remove(console)
    assert harness.spin_until(lambda: len(teleop.get_publishers_info_by_topic('/teleop_command')) == 1, timeout=10)
    harness.spin_until(lambda: False, timeout=0.6)
    rejected = teleop.rejected_commands
    rogue_pub.publish(command(-1.0))
    harness.spin_until(lambda: teleop.rejected_commands > rejected, timeout=5)
    assert teleop.rejected_commands > rejected


def test_a_ui_of_ones_own_is_refused_with_how_to_name_it_and_then_taken(harness, ros_context):
    """From outside: a person's UI written from the README (labelled teleop_command, take_over held)
    was refused with only `not by /advice_console or /keyboard_teleop`; command_publisher was unsaid."""
    said = []
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(source='array', axes=[0], scales=[2.0], offsets=[0.0], stale_after_s=5.0),
        )
    )
    logger = teleop.get_logger()
    teleop.get_logger = lambda: SimpleNamespace(
        info=logger.info, warn=logger.warn, error=lambda line, **k: said.append(line)
    )
    ui = harness.add(rclpy.create_node('my_ui', context=ros_context))
    pub = ui.create_publisher(Float32MultiArray, 'teleop_command', 10)
    assert harness.spin_until(lambda: pub.get_subscription_count() > 0)
    harness.spin_until(lambda: False, timeout=0.6)  # past the graph cache
    pub.publish(messages.command_msg([0.5], True, False, False, take_over=True))
    assert harness.spin_until(lambda: said, timeout=5)
    assert said[0] == (
        "commands refused: '/teleop_command' is published by ['/my_ui'], not by /advice_console or /keyboard_teleop "
        '(your own UI? take its commands: -p command_publisher:=/my_ui)'
    )
    named = harness.add(
        TeleopExpertNode(
            context=ros_context,
            namespace='/named',
            parameter_overrides=params(
                source='array', axes=[0], scales=[2.0], offsets=[0.0], command_publisher='/my_ui'
            ),
        )
    )
    taken, take = [], named._take
    named._take = lambda command: (taken.append(command), take(command))
    named_pub = ui.create_publisher(Float32MultiArray, '/named/teleop_command', 10)
    assert harness.spin_until(lambda: named_pub.get_subscription_count() > 0)
    harness.spin_until(lambda: False, timeout=0.6)
    named_pub.publish(messages.command_msg([0.5], True, False, False, take_over=True))
    assert harness.spin_until(lambda: taken, timeout=5)
    assert named.rejected_commands == 0 and taken[0].take_over and taken[0].values.tolist() == [1.0]


def test_a_strangers_word_on_learner_advice_request_ends_no_request_of_the_person(harness, ros_context):
    """teleop_expert ends a request the learner says it has closed (FAILED), and holds it while the
    learner says STOP holds it. Before, any node's message did so: a stranger that echoed the
    request on the person's screen as FAILED withdrew it, every time. Now the learner's word is
    taken only while one node alone publishes learner/advice_request."""
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            namespace='/guarded',
            parameter_overrides=params(source='array', axes=[0], scales=[2.0], offsets=[0.0], answer_window_s=30.0),
        )
    )
    learner = harness.add(rclpy.create_node('learner', namespace='/guarded', context=ros_context))
    rogue = harness.add(rclpy.create_node('rogue', namespace='/guarded', context=ros_context))
    said = learner.create_publisher(AdviceRequestMsg, 'learner/advice_request', messages.LATCHED_QOS)
    client = learner.create_client(Advise, 'advise')
    assert harness.spin_until(client.service_is_ready)
    request = Advise.Request(
        observation=[0.0, 0.0, 0.0], proposed_action=[0.0], action_low=[-2.0], action_high=[2.0], episode=3, step=7
    )
    future = client.call_async(request)
    assert harness.spin_until(lambda: teleop.expert.pending is not None)
    closed = AdviceRequestMsg(outcome=AdviceRequestMsg.FAILED, detail='timeout', episode=3, step=7)
    forged = rogue.create_publisher(AdviceRequestMsg, 'learner/advice_request', messages.LATCHED_QOS)
    topic = teleop.resolve_topic_name('learner/advice_request')
    assert harness.spin_until(lambda: len(teleop.get_publishers_info_by_topic(topic)) == 2, timeout=10)
    harness.spin_until(lambda: False, timeout=0.6)  # past the graph cache
    forged.publish(closed)
    harness.spin_until(lambda: False, timeout=1.0)
    assert teleop.ended_by_learner == 0 and teleop.expert.pending is not None and not future.done()
    harness.nodes.remove(rogue)
    rogue.destroy_node()  # the learner alone: its word ends the request
    assert harness.spin_until(lambda: len(teleop.get_publishers_info_by_topic(topic)) == 1, timeout=10)
    harness.spin_until(lambda: False, timeout=0.6)
    said.publish(closed)
    assert harness.spin_until(lambda: teleop.ended_by_learner == 1, timeout=5)
    assert harness.spin_until(future.done) and not future.result().advised


def test_with_a_shared_key_only_a_signed_command_answers(harness, ros_context, tmp_path):
    from eqhrl_ros.core.data.signing import CommandSeal, Signer, new_key_file, read_key

    key = str(new_key_file(tmp_path / 'deployment.key'))
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(
                source='array', axes=[0], scales=[2.0], offsets=[0.0], answer_mode='instant', key_file=key
            ),
        )
    )
    driver = harness.add(rclpy.create_node('advice_console', context=ros_context))
    pub = driver.create_publisher(Float32MultiArray, 'teleop_command', 10)
    client = driver.create_client(Advise, 'advise')
    assert harness.spin_until(lambda: pub.get_subscription_count() > 0)
    rejected = teleop.rejected_commands
    pub.publish(messages.command_msg([-1.0], True, False, False))  # unsigned, though alone on the topic
    pub.publish(messages.command_msg([-1.0], True, False, False, CommandSeal(Signer(b'another key, not ours!!'))))
    assert harness.spin_until(lambda: teleop.rejected_commands >= rejected + 2, timeout=5)
    seal = advise_msgs.request_seal(Signer(read_key(key)))
    assert 'no teleop command' in call_advise(harness, client, seal=seal).reason
    pub.publish(messages.command_msg([0.5], True, False, False, CommandSeal(Signer(read_key(key)))))
    harness.spin_until(lambda: False, timeout=0.3)
    response = call_advise(harness, client, seal=seal)
    assert response.advised and list(response.action) == pytest.approx([1.0])


def test_with_a_shared_key_a_strangers_call_of_advise_opens_nothing_for_the_person(harness, ros_context, tmp_path):
    """rclpy does not tell a service who calls: a stranger's well-formed call of teleop_expert's
    'advise' superseded the learner's request open on the person's screen. With key_file, a request
    not signed with it is declined at once and the open one stays; the person's answer is signed."""
    from eqhrl_ros.core.data.signing import CommandSeal, Signer, new_key_file, read_key

    key = str(new_key_file(tmp_path / 'deployment.key'))
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(
                source='array', axes=[0], scales=[2.0], offsets=[0.0], answer_window_s=30.0, key_file=key
            ),  # fmt: skip
        )
    )
    learner = harness.add(rclpy.create_node('learner', context=ros_context))
    driver = harness.add(rclpy.create_node('advice_console', context=ros_context))
    client = learner.create_client(Advise, 'advise')
    pub = driver.create_publisher(Float32MultiArray, 'teleop_command', 10)
    assert harness.spin_until(lambda: client.service_is_ready() and pub.get_subscription_count() > 0)
    seal = advise_msgs.request_seal(Signer(read_key(key)))

    def asked(episode, step, signed_with):
        request = Advise.Request(observation=[0.0, 0.0, 0.0], proposed_action=[0.0], action_low=[-2.0],
                                 action_high=[2.0], episode=episode, step=step)  # fmt: skip
        return request, client.call_async(advise_msgs.sign_request(request, signed_with))

    request, future = asked(3, 7, seal)
    assert harness.spin_until(lambda: teleop.expert.pending is not None)
    _, stranger = asked(4, 0, None)
    assert harness.spin_until(stranger.done, timeout=5)
    assert stranger.result().reason == 'request refused: it is unsigned and this node has a key_file'
    assert (teleop.expert.pending.request.episode, teleop.expert.pending.request.step) == (3, 7)
    assert not future.done()
    person = CommandSeal(Signer(read_key(key)))
    harness.spin_until(lambda: False, timeout=0.3)  # a reaction, not a command made before the request
    pub.publish(messages.command_msg([0.5], True, False, False, person, request=(3, 7)))  # steer
    pub.publish(messages.command_msg([0.5], True, True, False, person, request=(3, 7)))  # Enter
    assert harness.spin_until(future.done, timeout=10)
    answer = future.result()
    assert answer.advised and list(answer.action) == pytest.approx([1.0])
    assert advise_msgs.answer_refusal(answer, request, seal) == ''


def test_a_key_file_with_a_source_that_signs_nothing_is_refused(ros_context, tmp_path):
    from eqhrl_ros.core.data.signing import new_key_file

    key = str(new_key_file(tmp_path / 'deployment.key'))
    with pytest.raises(ValueError, match='sign nothing'):
        TeleopExpertNode(context=ros_context, parameter_overrides=params(source='joy', key_file=key))


def test_teleop_expert_passes_the_persons_command_on_for_a_takeover(harness, ros_context):
    harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(env_id='Pendulum-v1', source='array', axes=[0], scales=[3.0], offsets=[0.0]),
        )
    )
    driver = harness.add(rclpy.create_node('advice_console', context=ros_context))
    pub = driver.create_publisher(Float32MultiArray, 'teleop_command', 10)
    passed = []
    driver.create_subscription(Float32MultiArray, messages.PERSON_COMMAND_TOPIC, passed.append, 10)
    assert harness.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(messages.command_msg([0.9], True, False, False, take_over=True))
    assert harness.spin_until(lambda: passed, timeout=5)
    fields = messages.read_fields(passed[-1])
    assert fields['action'] == pytest.approx([2.0])  # 0.9 x 3 = 2.7, clipped to the env's bound
    assert fields['deadman'] == [1.0] and fields['take_over'] == [1.0]


def test_a_stranger_alone_on_teleop_command_answers_nothing_by_default(harness, ros_context):
    """Before: with the console not running, any node publishing teleop_command answered as the person."""
    teleop = harness.add(
        TeleopExpertNode(
            context=ros_context,
            parameter_overrides=params(source='array', axes=[0], scales=[2.0], offsets=[0.0], answer_mode='instant'),
        )
    )
    stranger = harness.add(rclpy.create_node('stranger', context=ros_context))
    pub = stranger.create_publisher(Float32MultiArray, 'teleop_command', 10)
    client = stranger.create_client(Advise, 'advise')
    assert harness.spin_until(lambda: pub.get_subscription_count() > 0)
    harness.spin_until(lambda: False, timeout=0.6)  # the graph has seen it
    pub.publish(messages.command_msg([-1.0], True, False, False))
    assert harness.spin_until(lambda: teleop.rejected_commands >= 1, timeout=5)
    assert 'no teleop command' in call_advise(harness, client).reason


def test_a_mapping_set_through_the_parameter_service_is_said_and_refused_as_a_list(harness, ros_context):
    """From outside, `ros2 param set /teleop_expert scales "[3.0]"`: rclpy hands the node an array.array,
    and the node said `set to array('d', [3.0])`, and refused `[.nan]` as `array('d', [nan])`."""
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    teleop = harness.add(TeleopExpertNode(context=ros_context, parameter_overrides=params(source='joy')))
    said = []
    teleop.get_logger = lambda: SimpleNamespace(info=said.append, warn=said.append, error=said.append)
    caller = harness.add(rclpy.create_node('param_caller', context=ros_context))
    client = AsyncParameterClient(caller, teleop.get_fully_qualified_name())
    assert harness.spin_until(lambda: client.services_are_ready())

    def set_scales(value):
        future = client.set_parameters([Parameter('scales', value=value)])
        assert harness.spin_until(future.done)
        return future.result().results[0]

    refused = set_scales([float('nan')])
    assert not refused.successful and refused.reason == "parameters 'scales' [nan] and 'offsets' [0.0] must be finite"
    assert set_scales([3.0]).successful
    assert said == ['parameter scales set to [3.0] (was [1.0])'] and teleop.params['scales'] == [3.0]


def test_keyboard_teleop_shows_no_request_whose_numbers_mean_nothing(harness, ros_context):
    """From outside: a node posing as the learner (while none ran) sent a request whose wait was
    infinite: the terminal counted down '… of inf s', and one with a NaN wait '… of nan s'. The
    terminal now checks a request as the person's page does, drops it and keeps the one before."""
    import io

    from eqhrl_ros.nodes.keyboard_teleop_node import KeyboardTeleop

    read_end, write_end = os.pipe()
    screen = io.StringIO()
    try:
        keyboard = harness.add(
            KeyboardTeleop(read_end, screen, context=ros_context, parameter_overrides=params(dimensions=1))
        )
        learner = harness.add(rclpy.create_node('learner', context=ros_context))
        said = learner.create_publisher(AdviceRequestMsg, 'learner/advice_request', messages.LATCHED_QOS)
        good = AdviceRequestMsg(
            outcome=AdviceRequestMsg.PENDING, episode=2, step=5, timeout_s=5.0, proposed_action=[0.5]
        )
        said.publish(good)
        assert harness.spin_until(lambda: keyboard.request is not None)
        for dropped, wait in enumerate((float('inf'), float('nan')), start=1):  # one at a time: latched, depth 1
            said.publish(AdviceRequestMsg(outcome=AdviceRequestMsg.PENDING, episode=9, step=9, timeout_s=wait))
            assert harness.spin_until(lambda: keyboard.dropped == dropped, timeout=5)
        keyboard.action_size = 1  # as the env's env_info says (unknown, an action's size is not judged)
        said.publish(AdviceRequestMsg(outcome=AdviceRequestMsg.PENDING, episode=9, step=9, proposed_action=[0.1, 0.2]))
        assert harness.spin_until(lambda: keyboard.dropped == 3, timeout=5)
        shown = screen.getvalue().split('\x1b[H')[-1]
        assert 'episode 9' not in shown and 'inf s' not in shown and 'nan s' not in shown
        assert (keyboard.request.episode, keyboard.request.step) == (2, 5)
    finally:
        os.close(read_end)
        os.close(write_end)
