"""eqhrl-experiment's runs: its settings written beside them, the runs handed to the pool (each
algorithm's seeds apart, or stacked in shares), and the wait for them with progress lines."""

from __future__ import annotations

import queue
import time
from pathlib import Path

import yaml

from .ros_runs import domain_ids
from .seed_runs import group_worker, run_dir, run_worker


def write_settings(output: Path, settings, args) -> None:
    """<output>/settings.yaml: what the runs were made with."""
    (output / 'settings.yaml').write_text(
        yaml.safe_dump(
            {
                'env_id': settings.env_id,
                'env_node': settings.env_node or settings.file_env_node,
                'episodes': settings.episodes,
                'max_episode_steps': settings.max_episode_steps,
                'algorithms': args.algorithms,
                'seeds': args.seeds,
                'expert': settings.expert_backend,
                'through_ros': args.through_ros,
                'eval_every': settings.eval_every,
                'eval_starts': settings.eval_starts,
                'params_file': settings.params_path,
                'learner': settings.learner,
            }
        )
    )


def submit_runs(pool, settings, algorithms, todo, output: Path, progress, together: bool, jobs: int, through_ros: bool):
    """The pool's tasks for ``todo`` ((algorithm, seed)): [(runs in the task, its async result)]."""
    if together:
        # Each algorithm's seeds in `jobs` shares, one process each, a share's seeds together.
        groups = []
        for algorithm in algorithms:
            seeds = [s for a, s in todo if a == algorithm]
            groups += [(algorithm, seeds[i::jobs]) for i in range(jobs) if seeds[i::jobs]]
        tasks = [
            (len(seeds), pool.apply_async(group_worker, (settings, a, seeds, output, progress))) for a, seeds in groups
        ]
    else:
        tasks = [
            (
                1,
                pool.apply_async(run_worker, (settings, a, s, run_dir(output, a, s), through_ros, progress, d)),
            )
            for (a, s), d in zip(todo, domain_ids(len(todo)))
        ]
    return tasks


def wait_for_runs(tasks, todo, output: Path, count, progress, cluster, start: float) -> None:
    """Until every task is done: episode counts from ``progress``, a line every 15 s and at each
    finished run; a worker's error is raised here."""
    last_print = 0.0
    finished_tasks = 0
    while finished_tasks < len(tasks):
        try:
            count.add(progress.get(timeout=0.5))
        except queue.Empty:
            pass
        newly = sum(r.ready() for _, r in tasks) - finished_tasks
        for _, r in tasks:
            if r.ready() and not r.successful():
                r.get()  # re-raise a worker's error here
        finished_tasks += newly
        now = time.monotonic()
        if now - last_print > 15.0 or newly:
            last_print = now
            runs_done = sum((run_dir(output, a, s) / 'DONE').exists() for a, s in todo)
            if cluster:  # no episode reports across hosts: finished runs only
                print(f'[{runs_done}/{len(todo)} runs, {(now - start) / 60:.1f} min]', flush=True)
            else:
                print(count.line(runs_done, len(todo), now - start), flush=True)
