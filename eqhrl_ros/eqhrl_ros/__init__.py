"""EQ-HRL for ROS 2. The package in wings, each importing only the wings above it in this list
(tests/test_structure.py holds it, and that every module is in a wing):

core/         the ROS-free learner: Algorithm 1, its parts, the experts, runs (core/__init__.py)
files/        the YAML files it reads, where its installed files are, the MCAP record
parameters/   every node's parameters, one table per node, read with or without ROS
nodes/        the ROS nodes: thin adapters over core/, one job per module
experiments/  the library of eqhrl-experiment and eqhrl-study: settings, runs, pools, plans
reports/      what the runs' CSVs say: statistics, tables and figures
cli/          the programs: each main parses, calls the wings above, and prints
web/          the person's page (console.html, console.js), served by nodes/console_server.py
"""

# OpenMP's spin is left as libgomp has it (or as you set it, GOMP_SPINCOUNT): torch's thread
# count is fitted to the machine instead (core/algorithm/cpu_threads.py). Until 2026-12-04 this
# package set 1,000 spins here; docs/performance.md, "Fitting torch's threads to the machine".
