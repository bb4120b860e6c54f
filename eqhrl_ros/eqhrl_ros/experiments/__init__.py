"""The library under eqhrl-experiment and eqhrl-study (their cli/ mains parse and print; this runs):

- settings.py   a params file's sections and the command line's overrides; a run's learner and expert
- seed_runs.py  one seed's run in this process (resumable), or an algorithm's seeds together
- ros_runs.py   one seed's run through the ROS nodes, in a private domain
- run_pool.py   the pool that runs them: local processes, or a Dask cluster (--cluster)
- progress.py   episodes done and time left
- gather.py     the finished runs' CSVs in one table
- study_plan.py a study's plan: its arms in groups of seeds, and each arm's settings
- study_runs.py a study's runs: what is finished, what a matched arm is matched to, the run loop

(The study's report, its statistics, tables and figures, is reports/.)
"""
