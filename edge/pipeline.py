"""The per-frame pipeline the vehicle service drives (the shared pipeline contract).

CAV side `mmatch.cav.process.process_view`, wire codec `mmatch.codec.encode/decode`,
Ego side `mmatch.fusion.fuse`. They are looked up when the service starts, so the edge
package imports without them and a test can hand in its own `Pipeline`.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mmatch.errors import MMatchError


@dataclass(frozen=True)
class Pipeline:
    """process_view(points, boxes, features, camera, radar_height, stamp, *, sender, seq)
    -> (SharedFrame, {stage: ms}); encode(SharedFrame) -> bytes; decode(bytes) -> SharedFrame
    (raises DecodeError); fuse(own, other | None) -> FusionResult; track_objects(own,
    [(other, FusionResult), ...]) -> ObjectFrame | None, once per Ego frame after fusing every
    CAV (None: objects are not tracked); idle() -> int, once per Ego frame after its result is
    published: work fusion deferred past the frame's latency (the tracker's regular full
    search; None: nothing to do)."""

    process_view: Callable[..., tuple[Any, dict[str, float]]]
    encode: Callable[[Any], bytes]
    decode: Callable[[bytes], Any]
    fuse: Callable[..., Any]
    track_objects: Callable[..., Any] | None = None
    idle: Callable[[], Any] | None = None


def _get(module: str, name: str) -> Callable:
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise MMatchError(f"pipeline: {module}.{name} is not available ({exc}); "
                          "the vehicle service needs the CAV processing, codec and fusion modules") from exc


def default_pipeline(*, need_fuse: bool = True, track_max_age_s: float = 0.0,
                     confidence_threshold: float | None = None) -> Pipeline:
    """The product pipeline; `need_fuse=False` lets a CAV run without the fusion module.

    The CAV side keeps its camera's depth scale calibrated across frames (mmatch/cav/depth_scale.py).

    track_max_age_s > 0: one Fuser for the whole run that carries each CAV's transform
    across frames (mmatch/ego/track/) for up to that long and tracks the fused objects.
    confidence_threshold: estimates less sure are "no estimate" (None or negative: the fitted
    model's threshold).

    $MMATCH_PIPELINE="module:attr" names another `Pipeline` (for tests and experiments).
    """
    override = os.environ.get("MMATCH_PIPELINE")
    if override:
        module, _, attr = override.partition(":")
        pipe = _get(module, attr or "PIPELINE")
        if not isinstance(pipe, Pipeline):
            raise MMatchError(f"pipeline: $MMATCH_PIPELINE={override!r} is not a Pipeline")
        return pipe
    fuse, track_objects, idle = _no_fuse, None, None
    if need_fuse:
        fuser, fusion_config = _get("mmatch.fusion", "Fuser"), _get("mmatch.fusion", "FusionConfig")
        track_config = _get("mmatch.ego.track", "TrackConfig")
        confidence_config = _get("mmatch.ego.confidence", "ConfidenceConfig")
        thr = None if confidence_threshold is None or confidence_threshold < 0 else float(confidence_threshold)
        one = fuser(fusion_config(track=track_config(max_age_s=track_max_age_s),
                                  confidence=confidence_config(threshold=thr)))
        fuse = one.fuse
        track_objects = one.track_objects if track_max_age_s > 0 else None
        idle = one.run_deferred
    view_processor = _get("mmatch.cav.process", "ViewProcessor")      # its camera's depth calibration
    return Pipeline(process_view=view_processor(),
                    encode=_get("mmatch.codec", "encode"), decode=_get("mmatch.codec", "decode"),
                    fuse=fuse, track_objects=track_objects, idle=idle)


def _no_fuse(*a: Any, **k: Any) -> Any:
    raise MMatchError("fusion is not available in this role")
