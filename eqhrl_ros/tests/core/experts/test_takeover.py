"""The person's takeover rule (core/experts/takeover.py), as the acting node applies it each step."""

import numpy as np

from eqhrl_ros.core.envs.spec import ActionScaler
from eqhrl_ros.core.experts.takeover import TAKEOVER_STALE_S, DeadmanTakeover, PersonCommand

SCALER = ActionScaler([-2.0], [2.0])


def command(action, deadman=True, take_over=False, at=100.0):
    return PersonCommand(np.asarray([action], np.float32), deadman, take_over, at)


def test_the_take_over_button_starts_a_stretch_that_lasts_while_the_deadman_is_held():
    rule = DeadmanTakeover(SCALER, threshold=0.0)
    assert rule.person_drives(command(1.0), [1.5], 100.0) is None  # deadman alone: the learner drives
    step = rule.person_drives(command(1.0, take_over=True), [1.5], 100.0)
    assert step.starts and step.seconds == 0.0 and step.action[0] == 1.0
    rule.taken(100.0, accepted=True)
    later = rule.person_drives(command(-1.0, at=100.1), [1.5], 100.1)  # button released, deadman held
    assert not later.starts and abs(later.seconds - 0.1) < 1e-6
    rule.taken(100.1, accepted=True)
    assert rule.person_drives(command(-1.0, deadman=False, at=100.2), [1.5], 100.2) is None
    assert rule.hand_back() and not rule.taking_over and not rule.hand_back()


def test_steering_away_takes_over_only_where_the_threshold_is_on():
    off = DeadmanTakeover(SCALER, threshold=0.0)
    assert off.person_drives(command(2.0), [-2.0], 100.0) is None
    on = DeadmanTakeover(SCALER, threshold=0.5)
    assert on.person_drives(command(0.8), [0.0], 100.0) is None  # 0.4 apart in [-1, 1] units
    assert on.person_drives(command(1.2), [0.0], 100.0).starts  # 0.6 apart


def test_a_stale_command_or_one_of_the_wrong_size_never_drives():
    rule = DeadmanTakeover(SCALER, threshold=0.0)
    assert rule.person_drives(command(1.0, take_over=True, at=100.0), [0.0], 100.0 + TAKEOVER_STALE_S + 0.01) is None
    wrong = PersonCommand(np.zeros(2, np.float32), True, True, 100.0)
    assert rule.person_drives(wrong, [0.0], 100.0) is None
    assert rule.person_drives(None, [0.0], 100.0) is None
    rule.taken(100.0, accepted=False)  # an action the learner refused ends the stretch
    assert not rule.taking_over
