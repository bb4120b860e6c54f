"""The progress line of a pool of runs (experiments/progress.py)."""

from eqhrl_ros.experiments import progress


def test_the_progress_line_counts_a_resumed_runs_earlier_episodes_as_done_and_times_only_this_process():
    count = progress.EpisodeCount(total=20)  # two runs of 10 episodes
    assert count.line(0, 2, 3.0) == '[0/20 episodes, 0/2 runs]   0.0%  eta     ? min'  # before: 'eta   nan min'
    for message in [('eqsac', 0, 6, -1.0), ('sac', 0, 0, -2.0), ('eqsac', 0, 7, -1.0), ('sac', 0, 1, -2.0)]:
        count.add(message)  # eqsac seed 0 resumed after episode 6; sac seed 0 fresh
    assert count.done == 10
    # 4 episodes in 40 s here: the 10 left take 100 s
    assert count.line(0, 2, 40.0) == '[10/20 episodes, 0/2 runs]  50.0%  eta   1.7 min'
