"""Over time: a multi-hypothesis filter on T_ego_cav per CAV (filter.py) and its keeper (predict.py)."""

from mmatch.ego.track.predict import TrackConfig, Tracker

__all__ = ["TrackConfig", "Tracker"]
