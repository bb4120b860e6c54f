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

import os

# torch's CPU threads come from OpenMP (libgomp), whose idle threads spin about 300,000 times
# before they sleep. Beside another busy process (a simulator, a camera driver, a second run)
# they spin against it for the cores, and a learner kept 27 % of its quiet speed. With 1,000
# spins it keeps 48-51 % (its fair share beside one busy process on 2 cores is 50 %) at 96-98 %
# of the quiet speed (docs/performance.md, "A busy machine"). libgomp reads this once, when
# torch loads it: set here, before any of our modules imports torch. A value you set wins.
os.environ.setdefault('GOMP_SPINCOUNT', '1000')
