"""Advice-free evaluation: the policy alone from fixed start states, without
changing what training does."""

from eqhrl_ros.core import EQSACLearner, LearnerConfig, heuristic_expert, make_env, train
from eqhrl_ros.core.runs.evaluation import eval_seeds, evaluate
from eqhrl_ros.core.runs.in_process import Evaluation


def pendulum_learner() -> EQSACLearner:
    config = LearnerConfig(
        mode='eqsac', hidden=(16, 16), batch_size=16, learning_starts=40, queue_length=3, advising_budget=3
    )
    return EQSACLearner(3, [-2.0], [2.0], config)


def test_evaluating_changes_nothing_in_training_and_comes_every_k_episodes():
    expert = heuristic_expert('Pendulum-v1')
    plain = train(make_env('Pendulum-v1', 30), pendulum_learner(), 5, expert, seed=3)
    results = []
    evaluated_learner = pendulum_learner()
    evaluation = Evaluation(make_env('Pendulum-v1', 30), 2, eval_seeds(3), results.append)
    evaluated = train(make_env('Pendulum-v1', 30), evaluated_learner, 5, expert, seed=3, evaluation=evaluation)
    assert [s.episode_return for s in evaluated] == [s.episode_return for s in plain]  # to the bit
    assert sum(s.advice_given for s in plain) > 0  # the training returns include advice
    assert [[r.after_episode for r in rs] for rs in results] == [[2] * 3, [4] * 3, [5] * 3]
    assert [r.start for r in results[0]] == eval_seeds(3) == [1_000_000, 1_000_001, 1_000_002]
    assert all(r.length == 30 for rs in results for r in rs)
    # Deterministic: the same weights from the same start states give the same returns.
    again = evaluate(make_env('Pendulum-v1', 30), evaluated_learner, eval_seeds(3))
    assert [r.episode_return for r in again] == [r.episode_return for r in results[-1]]
    assert len({r.episode_return for r in again}) == 3  # three different start states


def test_success_is_judged_by_the_learners_rule_without_touching_the_training_episodes():
    learner = pendulum_learner()
    learner.success.update([1.0, 0.0, 0.0], -0.1)  # mid-episode state of the training criterion
    state = dict(vars(learner.success))
    results = evaluate(make_env('Pendulum-v1', 20), learner, eval_seeds(2))
    assert dict(vars(learner.success)) == state
    assert all(r.success in (True, False) for r in results)
