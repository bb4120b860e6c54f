"""EQ-HRL itself: the hyperparameters, the paper's equations, the networks, Algorithm 1's update
(eager, compiled, many seeds at once), the advising gates and the learner. Imports data/ and envs/."""
