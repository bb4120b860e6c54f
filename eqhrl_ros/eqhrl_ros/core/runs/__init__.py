"""A run from start to end: the in-process training loops, the trainer fed by actors, checkpoints,
resume points, the run's record (episodes.csv) and the advice-free evaluation. The top wing."""
