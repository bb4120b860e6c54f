"""Running a study: which runs are finished, what a matched arm's run is matched to, and the
pool that runs the rest, group by group and seed by seed (eqhrl-study's docstring)."""

from __future__ import annotations

import csv
import dataclasses
import queue
import sys
import time
from pathlib import Path

import yaml

from . import gather as gathering
from .run_pool import ClusterUnavailable, RunFailed, progress_queue, run_pool, stopping_like_ctrl_c
from .seed_runs import GATE_FIELDS, run_dir, run_worker
from .study_plan import Arm, Plan, budget_of


def requests_per_episode(run: Path, budget: int) -> list[tuple[int, int]]:
    """(requests, steps) of each of the first ``budget`` episodes of a finished run, in order."""
    rows = {}
    with (run / 'episodes.csv').open(newline='') as f:
        for row in csv.DictReader(f):
            if int(row['episode']) < budget:
                rows[int(row['episode'])] = (int(row['advice_asked']), int(row['length']))
    return [rows.get(e, (0, 0)) for e in range(max(rows) + 1)] if rows else []


def requested_steps(run: Path, budget: int) -> list[int]:
    """random_ask_steps of a finished run with a gate trace: for each of its first ``budget``
    episodes, its length and the steps it asked at, then -1."""
    fired: dict = {}
    with (run / 'gates.csv').open(newline='') as f:
        for row in csv.DictReader(f):
            if int(row['episode']) < budget and int(float(row['fire'])):
                fired.setdefault(int(row['episode']), []).append(int(row['step']))
    flat = []
    for episode, (_, length) in enumerate(requests_per_episode(run, budget)):
        flat += [max(1, length), *sorted(set(fired.get(episode, ())))]
        flat.append(-1)
    return flat


def matched_rate(run: Path, budget: int) -> tuple[float, int, int]:
    """(requests per step, requests, steps) inside the first ``budget`` episodes of a finished run."""
    episodes = requests_per_episode(run, budget)
    asked, steps = sum(a for a, _ in episodes), sum(n for _, n in episodes)
    return (asked / steps if steps else 0.0), asked, steps


def run_minutes(run: Path):
    """How long a finished run took: the seconds its DONE mark holds (a lone run's own time,
    earlier processes included), which survive a copy or a clone of the folder; for a mark
    without them, from its STARTED mark (a resumed run's last start) to DONE's time. None if
    neither tells."""
    try:
        return max(0.0, float((run / 'DONE').read_text().strip()) / 60)
    except (OSError, ValueError):
        pass
    try:
        return max(0.0, ((run / 'DONE').stat().st_mtime - (run / 'STARTED').stat().st_mtime) / 60)
    except OSError:
        return None


def write_arms(output: Path, plan: Plan) -> None:
    """<output>/arms.csv: what each arm is (and, for matched arms, each seed's rate in match.yaml)."""
    with (output / 'arms.csv').open('w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(('arm', 'label', 'group', 'mode', 'seeds', 'learner', 'expert', 'match'))
        for arm in plan.arms:
            writer.writerow(
                (
                    arm.name,
                    arm.label,
                    arm.group,
                    arm.mode,
                    ' '.join(map(str, arm.seeds)),
                    yaml.safe_dump(arm.learner, default_flow_style=True).strip() if arm.learner else '',
                    yaml.safe_dump(arm.expert, default_flow_style=True).strip() if arm.expert else '',
                    arm.match,
                )
            )


def gather(output: Path, plan: Plan) -> None:
    arms = [a.name for a in plan.arms]
    seeds = sorted({s for a in plan.arms for s in a.seeds})
    gathering.gather(output, arms, seeds, label='arm')
    rows = []
    for arm in plan.arms:
        for seed in arm.seeds:
            run = run_dir(output, arm.name, seed)
            if (run / 'DONE').exists() and (run / 'gates.csv').exists():
                with (run / 'gates.csv').open(newline='') as f:
                    rows += [[arm.name, seed, *r.values()] for r in csv.DictReader(f)]
    if rows:
        with (output / 'gates.csv').open('w', newline='') as f:
            writer = csv.writer(f)
            writer.writerow(('arm', 'seed', *GATE_FIELDS))
            writer.writerows(rows)


def ready_settings(plan: Plan, arm: Arm, seed: int, output: Path, settings: dict):
    """The settings to run (arm, seed) with, or None while the run it matches is unfinished."""
    own = settings[arm.name]
    if not arm.match:
        return own
    matched = run_dir(output, arm.match, seed)
    thinned = run_dir(output, arm.thins, seed) if arm.thins else None
    if not (matched / 'DONE').exists() or (thinned and not (thinned / 'DONE').exists()):
        return None
    rate, asked, steps = matched_rate(matched, budget_of(settings[arm.match]))
    record = {'matches': arm.match, 'requests': asked, 'steps': steps}
    if arm.thins:  # ask_random: the matched arm's requests over the thinned one's
        _, thin_asked, _ = matched_rate(thinned, budget_of(settings[arm.thins]))
        rate = min(1.0, asked / thin_asked) if thin_asked else 0.0
        learner = {'random_ask_rate': rate}
        record.update(thins=arm.thins, thinned_requests=thin_asked, random_ask_rate=rate)
    elif arm.match_timing == 'steps':
        steps = requested_steps(matched, budget_of(settings[arm.match]))
        learner = {'random_ask_steps': steps}
        record.update(random_ask_steps=steps)
    elif arm.match_timing == 'episode':
        schedule = [a for a, _ in requests_per_episode(matched, budget_of(settings[arm.match]))]
        learner = {'random_ask_schedule': schedule, 'random_ask_horizon': own.max_episode_steps}
        record.update(random_ask_schedule=schedule, random_ask_horizon=own.max_episode_steps)
    else:
        learner = {'random_ask_rate': rate}
        record.update(random_ask_rate=rate)
    run = run_dir(output, arm.name, seed)
    run.mkdir(parents=True, exist_ok=True)
    (run / 'match.yaml').write_text(yaml.safe_dump(record, default_flow_style=None))
    return dataclasses.replace(own, learner={**own.learner, **learner})


def time_left(output: Path, plan: Plan, done: list, todo: list, jobs: int) -> str:
    """'; about N min (M min a run so far)' from the finished runs' times, or why there is none."""
    durations = [d for d in (run_minutes(run_dir(output, a.name, s)) for a, s in done) if d is not None]
    if not todo:
        return ''
    if durations:
        per_run = sum(durations) / len(durations)
        left = per_run * len(todo) / max(1, min(jobs, len(todo)))
        return f'; about {left:.0f} min ({per_run:.1f} min a run so far)'
    return '; no time estimate yet (no finished run here says how long it took)'


def run_study(plan: Plan, settings: dict, output: Path, todo: list, jobs: int, cluster) -> tuple[int, int]:
    """Run ``todo`` ((arm, seed) in order), ``jobs`` at a time (or on the Dask cluster at
    ``cluster``); a matched run starts once the run it matches is finished. Gathers after each
    run. Returns (exit status, runs finished)."""
    start = time.monotonic()
    finished, pending, running = 0, list(todo), {}
    try:
        with (
            stopping_like_ctrl_c(),
            progress_queue(cluster) as progress,
            run_pool(max(1, min(jobs, len(todo) or 1)), cluster) as pool,
        ):
            if cluster:
                print(f'on the Dask cluster at {cluster}: {pool.slots} worker threads', flush=True)
            while pending or running:
                for key, result in list(running.items()):
                    if result.ready():
                        result.get()  # a worker's error ends the study here; finished runs are kept
                        del running[key]
                        finished += 1
                        arm, seed = key
                        elapsed = (time.monotonic() - start) / 60
                        left = elapsed / finished * (len(todo) - finished)  # at this process's pace so far
                        print(
                            f'[{finished}/{len(todo)} runs, {elapsed:.1f} min, about {left:.0f} min left] '
                            f'{arm} seed {seed} done',
                            flush=True,
                        )
                        gather(output, plan)  # a study read half-way (or killed) has its runs gathered
                for arm, seed in list(pending):
                    if len(running) >= (pool.slots if cluster else jobs):
                        break
                    ready = ready_settings(plan, arm, seed, output, settings)
                    if ready is None:
                        continue  # its matched run is not finished yet
                    pending.remove((arm, seed))
                    started = run_dir(output, arm.name, seed)
                    started.mkdir(parents=True, exist_ok=True)
                    (started / 'STARTED').touch()
                    running[(arm.name, seed)] = pool.apply_async(
                        run_worker,
                        (ready, arm.mode, seed, run_dir(output, arm.name, seed), False, progress, 0),
                    )
                while True:  # progress is only for the Manager's sake here: drain it
                    try:
                        progress.get_nowait()
                    except queue.Empty:
                        break
                if pending and not running:
                    stuck = ', '.join(
                        f'{a.name} seed {s} (matches {" and ".join(filter(None, (a.match, a.thins)))})'
                        for a, s in pending
                    )
                    print(f'eqhrl-study: waiting on runs outside this selection: {stuck}', file=sys.stderr)
                    return 2, finished
                time.sleep(0.5)
    except KeyboardInterrupt:
        print('\ninterrupted: finished runs are kept; run the same command to continue', file=sys.stderr)
        gather(output, plan)
        return 130, finished
    except ClusterUnavailable as error:
        print(f'eqhrl-study: {error}', file=sys.stderr)
        return 2, finished
    except RunFailed as error:
        print(f'eqhrl-study: {error}; finished runs are kept: run the same command to continue', file=sys.stderr)
        gather(output, plan)
        return 1, finished
    gather(output, plan)
    print(f'{finished} runs finished in {(time.monotonic() - start) / 60:.1f} min; gathered in {output}')
    return 0, finished
