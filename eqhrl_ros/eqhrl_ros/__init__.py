"""EQ-HRL for ROS 2: ``core`` holds the ROS-free learner, ``nodes`` the thin ROS adapters."""

import os

# torch's CPU threads come from OpenMP (libgomp), whose idle threads spin about 300,000 times
# before they sleep. Beside another busy process (a simulator, a camera driver, a second run)
# they spin against it for the cores, and a learner kept 27 % of its quiet speed. With 1,000
# spins it keeps 48-51 % (its fair share beside one busy process on 2 cores is 50 %) at 96-98 %
# of the quiet speed (docs/performance.md, "A busy machine"). libgomp reads this once, when
# torch loads it: set here, before any of our modules imports torch. A value you set wins.
os.environ.setdefault('GOMP_SPINCOUNT', '1000')
