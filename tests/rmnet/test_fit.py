"""The training loop's early stopping: never before `min_epochs`, then after `patience` stale epochs."""

from __future__ import annotations

from .conftest import require_torch


def _epochs_run(min_epochs: int) -> int:
    from mmatch.train.data import synthetic_samples
    from mmatch.train.fit import FitConfig, fit

    samples = synthetic_samples(5, 6, (3, 5))
    # a rate of zero: the validation loss never improves after the first epoch
    cfg = FitConfig(epochs=6, patience=1, min_epochs=min_epochs, lr=0.0, batch=4)
    _, history = fit(samples[:4], samples[4:], cfg)
    return len(history)


def test_early_stopping_waits_for_min_epochs():
    require_torch()
    assert _epochs_run(0) == 2
    assert _epochs_run(4) == 4
    assert _epochs_run(10) == 6
