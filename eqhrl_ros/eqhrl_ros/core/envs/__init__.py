"""Environments as the learner sees them: an env's spaces, pace and success rule (spec.py, no
gymnasium) and the gymnasium adapter (gymnasium_envs.py). Imports only data/."""
