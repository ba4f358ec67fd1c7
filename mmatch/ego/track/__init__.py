"""Over time: carry T_ego_cav from frame to frame."""

from mmatch.ego.track.predict import TrackConfig, Tracker

__all__ = ["TrackConfig", "Tracker"]
