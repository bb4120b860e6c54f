"""Progress of a command's runs, counted in episodes."""

from __future__ import annotations


class EpisodeCount:
    """The progress line of a command's runs: episodes done of ``total``, where a resumed run's
    earlier episodes count as done (its first report here is episode E, not 0), and the time
    left from the rate of the episodes run in this process only."""

    def __init__(self, total: int):
        self.total = total
        self.next_episode = {}  # (algorithm, seed) -> episodes the run has done
        self.run_here = 0

    def add(self, report) -> None:
        """One progress report: (algorithm, seed, episode, return)."""
        algorithm, seed, episode, _ = report
        self.next_episode[(algorithm, seed)] = max(self.next_episode.get((algorithm, seed), 0), int(episode) + 1)
        self.run_here += 1

    @property
    def done(self) -> int:
        return sum(self.next_episode.values())

    def line(self, runs_done: int, runs: int, seconds: float) -> str:
        rate = self.run_here / max(seconds, 1e-9)
        # No episode finished here yet: no rate to go by (before: 'eta nan min').
        eta = f'{(self.total - self.done) / rate / 60:5.1f} min' if rate > 0 else '    ? min'
        return (
            f'[{self.done}/{self.total} episodes, {runs_done}/{runs} runs] '
            f'{100 * self.done / max(self.total, 1):5.1f}%  eta {eta}'
        )
