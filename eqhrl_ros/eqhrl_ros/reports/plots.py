"""Figures from a learner's episodes.csv: return and advice per episode."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


def read_episodes(csv_path) -> dict[str, np.ndarray]:
    with Path(csv_path).open(newline='') as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f'{csv_path} holds no episodes')
    return {key: np.array([float(r[key]) for r in rows]) for key in rows[0]}


def smooth(values: np.ndarray, window: int = 11) -> np.ndarray:
    """Savitzky-Golay smoothing (Table 1's filter); short series are returned as they are."""
    from scipy.signal import savgol_filter

    window = min(window, len(values) - (1 - len(values) % 2))  # odd and <= len
    if window < 5:
        return values
    return savgol_filter(values, window, polyorder=2)


def plot_training(csv_path, png_path, title: str = '') -> Path:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    data = read_episodes(csv_path)
    episodes = data['episode']
    fig, (ax_return, ax_advice) = plt.subplots(2, 1, figsize=(8, 6), sharex=True, gridspec_kw={'height_ratios': [2, 1]})
    ax_return.plot(episodes, data['return'], color='tab:blue', alpha=0.3, label='return')
    ax_return.plot(episodes, smooth(data['return']), color='tab:blue', label='return (Savitzky-Golay)')
    ax_return.set_ylabel('episode return')
    ax_return.legend(loc='lower right')
    ax_return.grid(alpha=0.3)
    ax_advice.bar(episodes, data['advice_asked'], color='tab:orange', alpha=0.4, label='asked')
    ax_advice.bar(episodes, data['advice_given'], color='tab:orange', label='given')
    ax_advice.set_ylabel('advice per episode')
    ax_advice.set_xlabel('episode')
    ax_advice.legend(loc='upper right')
    ax_advice.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    png_path = Path(png_path)
    fig.savefig(png_path, dpi=100)
    plt.close(fig)
    return png_path
