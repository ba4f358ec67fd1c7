"""What `mmatch train` was asked to do, checked before anything heavy is imported (no torch here)."""

from __future__ import annotations

from dataclasses import dataclass

from mmatch.errors import ConfigError


@dataclass(frozen=True)
class TrainRequest:
    out: str
    export: str | None = None
    scenes: int = 14400                # the shipped model's recipe (mmatch/models/rmnet.md)
    physics: str = "wide"
    dense_scenes: int = 0
    dense_vehicles: str = "60-150"
    synthetic_scenes: int = 1800
    synthetic_vehicles: str = "10-45"
    val_share: float = 0.1
    seed: int = 1000
    train_seed: int = 0
    epochs: int = 48                   # the cosine schedule's length
    patience: int = 8
    min_epochs: int = 36               # no early stop before this many epochs (the rate still high; more than
                                       # epochs: the whole schedule runs)
    steps: int = 3
    jobs: int = 2
    threads: int = 2                   # 1 beside other jobs: two threads on a shared, busy 2-core machine crawl
    samples: str | None = None
    appearance_augment: float = 0.5    # probability of each appearance rewrite of a training graph (augment.py)

    @classmethod
    def from_args(cls, args) -> TrainRequest:
        req = cls(**{k: getattr(args, k) for k in cls.__dataclass_fields__})
        req.check()
        return req

    def check(self) -> None:
        if self.scenes < 4:
            raise ConfigError(f"scenes: {self.scenes} is too few (at least 4)")
        if not 0 < self.val_share < 1:
            raise ConfigError(f"val_share: {self.val_share} must lie between 0 and 1")
        if not 0 <= self.appearance_augment <= 1:
            raise ConfigError(f"appearance_augment: {self.appearance_augment} must lie between 0 and 1")
        if self.epochs < 1 or self.steps < 1 or self.jobs < 1 or self.threads < 1 or self.patience < 1:
            raise ConfigError("epochs, patience, steps, jobs and threads must be at least 1")
        if self.min_epochs < 0:
            raise ConfigError(f"min_epochs: {self.min_epochs} must be at least 0")
        parse_range(self.dense_vehicles, "dense_vehicles")
        lo, _ = parse_range(self.synthetic_vehicles, "synthetic_vehicles")
        if lo < 2:
            raise ConfigError(f"synthetic_vehicles: {self.synthetic_vehicles!r} needs at least 2 vehicles a view")


def parse_range(text: str, key: str) -> tuple[int, int]:
    """'LO-HI' -> (LO, HI), 0 <= LO <= HI; a broken value names the key."""
    try:
        lo, hi = (int(x) for x in str(text).split("-"))
    except ValueError:
        raise ConfigError(f"{key}: {text!r} is not LO-HI (two whole numbers)") from None
    if lo < 0 or hi < lo:
        raise ConfigError(f"{key}: {text!r} needs 0 <= LO <= HI")
    return lo, hi
