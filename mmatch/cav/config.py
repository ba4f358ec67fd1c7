"""Settings of the CAV-side stages: one frozen dataclass per stage, nested in `CavConfig`.

Defaults live here; `CavConfig.from_dict` builds one from a parsed config file and rejects
unknown keys and impossible values with `ConfigError` naming the key.

The separation and clustering defaults were chosen on simulated scenes (`mmatch sim`, 200
hard + 200 mixed, alignment success with the oracle matcher): they sit on a plateau where
changing any one of them (box margin 0-15 px, depth windows, DBSCAN radii, moving ratio,
elevation margin) moves the mean success by no more than about 2 points, except wider
box margins, which let guardrail and facade returns in and cost up to 6 points.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from mmatch.cav.accuracy import RadarAccuracyConfig
from mmatch.errors import ConfigError


@dataclass(frozen=True)
class EgoMotionConfig:
    """Doppler ego-motion fit (RANSAC over 2-point sets, then least squares on the inliers).

    threshold_mps: a point is stationary when |doppler residual| <= threshold, m/s, at boresight.
    threshold_growth_mps: added to the threshold at |azimuth| = edge_az_deg, growing as
        (|az| / edge_az)^2 (Doppler noise grows off boresight), m/s.
    hypotheses: number of 2-point hypotheses drawn at once.
    min_pair_sin: a hypothesis pair needs |sin(az_i - az_j)| above this (conditioning).
    refine_iterations: least-squares / inlier re-selection rounds after RANSAC.
    min_points: fewer finite points than this gives status "too-few-points".
    min_bearing_spread_deg: azimuth spread (max - min) of the points / inliers below this
        gives status "degenerate-bearing".
    min_inliers: fewer stationary inliers than this gives status "no-consensus".
        Stationary structure spans a wide bearing range; one vehicle or a platoon at one
        velocity spans a few degrees, so the two guards (6 inliers over >= 15 deg) turn most
        frames without background (a few clutter points, or a truck filling the view) into
        "no estimate" instead of a wrong velocity: on 300 simulated frames 16 gave no
        estimate and the p99 error fell from 14 to 0.9 m/s (median 0.03 either way).
    min_forward_mps: prior on the radar's motion: hypotheses whose velocity along the
        boresight (vy) is below this are discarded (a forward-looking radar on a vehicle
        reverses slowly if at all). Without it a frame whose only consistent points are a
        platoon of vehicles yields their relative velocity (vy = -5 to -8 m/s seen in
        simulation). Set it to -inf for a radar looking backwards or sideways.
    max_speed_mps: a fitted speed above this (m/s) is no estimate (junk input).
    seed: seed of the hypothesis sampler (the fit is deterministic per frame).
    threshold_sigma: > 0: after the fit each point's threshold becomes this many standard
        deviations of its stationary Doppler residual under the radar's accuracy model
        (section `radar`, cav/accuracy.py), never below threshold_floor_mps; 0 keeps the
        fixed bearing-dependent thresholds above.
    """

    threshold_mps: float = 0.35
    threshold_growth_mps: float = 0.45
    edge_az_deg: float = 60.0
    hypotheses: int = 160
    min_pair_sin: float = 0.08
    refine_iterations: int = 3
    min_points: int = 3
    min_bearing_spread_deg: float = 15.0
    min_inliers: int = 6
    min_forward_mps: float = -3.0
    max_speed_mps: float = 100.0
    seed: int = 0
    threshold_sigma: float = 3.0
    threshold_floor_mps: float = 0.25


@dataclass(frozen=True)
class SeparationConfig:
    """Frustum separation of vehicle points per camera box (paper, section "separation").

    delta_d_m: fixed half-width of the depth window around the box depth, m.
    depth_rel: extra half-width as a fraction of the depth (monocular depth error 5-15 %),
        for the points projecting into the box (moving or not).
    moving_depth_rel: the same for moving points in the box's bearing wedge; wider, since
        a moving point in the wedge is strong evidence and depth errors reach 2 sigma (30 %).
    box_margin_px: the box grows by this many pixels on every side before the tests
        (0: the in-box test uses the box as detected; wider margins let guardrail and
        facade returns beside a parked car in).
    bearing_margin_deg: the wedge for moving points also grows sideways by this angle
        (radar azimuth noise, 0.3-2.5 deg); used when bearing_margin_sigma is 0.
    bearing_margin_sigma: > 0: the wedge grows instead by this many standard deviations of
        each point's own azimuth error (from its SNR and angle, section `radar`) combined
        with glint_share of the box's angular width (a vehicle's returns wander over it).
    learned: points go to boxes by the learned membership (cav/membership.py, its packaged
        model or membership_model when set) instead of the fixed tests below, which stay
        for a deployment without a model.
    doppler_assign: a point claimed by several boxes goes to the one its depth and Doppler
        agree with (else: the box whose depth is nearest its range). Off by default: on
        200 wide hard scenes (seed 1) it cost 2 points of pair F1 (the box motions it
        compares come from the same few contested points).
    elevation_margin_deg: the in-box test grows vertically by this angle (radar elevation
        noise is several degrees: a vehicle's returns often project above or below its box;
        on 200 wide hard scenes 2 deg gave pair F1 0.738 against 0.725 at 4 deg: wider
        margins let the roadside behind parked cars in).
    edge_px: a box within this many pixels of the image's left or right edge is cut by
        it: its box and wedge open to that side (the vehicle continues outside the image).
    min_box_score: boxes scoring below this are ignored (not vehicles).
    moving_ratio: a box is a moving vehicle when it claims at least one moving point and at
        least `moving_ratio` times as many moving as stationary points; otherwise it is
        parked (a lone ghost or clutter point in a parked car's box does not make it move;
        2 on wide physics: parked cars beside traffic catch passing returns, 0.5 cost 2.6
        points of pair F1 on 200 wide hard scenes).
    parked_keep_points: a box that is not moving (parked car, or a vehicle crossing
        the line of sight) keeps the stationary points it claims as its vehicle points; when
        False they go to the background and the vehicle is shared without points.
    min_camera_z_m: points closer than this in front of the camera never project.
    grow_eps_m / grow_velocity_scale_s / grow_margin_deg: an unclaimed moving point within
        grow_eps_m (in x, y, scale * Doppler residual) of a box's moving point, and within
        grow_margin_deg of that box's columns and its depth window, joins that box (radar
        azimuth noise pushes returns just outside the wedge); 0 turns it off.
    """

    delta_d_m: float = 3.0
    depth_rel: float = 0.15
    moving_depth_rel: float = 0.3
    box_margin_px: float = 0.0
    bearing_margin_deg: float = 0.5
    bearing_margin_growth_deg: float = 0.0
    bearing_margin_sigma: float = 2.0
    glint_share: float = 0.15
    doppler_assign: bool = False
    learned: bool = True
    membership_model: str = ""
    elevation_margin_deg: float = 2.0
    edge_px: float = 0.0
    min_box_score: float = 0.0
    min_camera_z_m: float = 0.5
    parked_keep_points: bool = True
    moving_ratio: float = 2.0
    grow_eps_m: float = 3.0
    grow_velocity_scale_s: float = 1.0
    grow_margin_deg: float = 2.0


@dataclass(frozen=True)
class PlausibilityConfig:
    """Which camera boxes the radar contradicts (cav/plausibility.py).

    containment: share of a box's area inside a better box that makes it a duplicate;
    duplicate_depth_rel / duplicate_depth_m: the two depths agree within this (relative + fixed);
    see_through_points: returns beyond the box that show the radar sees past it;
    see_through_margin_rel / _m: how far beyond the box depth a return must lie (relative + fixed);
    see_through_max_m: beyond this depth a box is never called a see-through (weak returns,
    vehicles whose returns fade); 0 turns the check off (the default: on 200 wide hard
    scenes it dropped 22 of 931 true boxes with 71 false ones and cost 3 points of pair
    recall for 0.2 of precision); enabled: all checks on or off.
    """

    enabled: bool = True
    containment: float = 0.7
    duplicate_depth_rel: float = 0.15
    duplicate_depth_m: float = 2.0
    see_through_points: int = 2
    see_through_margin_rel: float = 0.3
    see_through_margin_m: float = 4.0
    see_through_max_m: float = 0.0


@dataclass(frozen=True)
class ClusteringConfig:
    """DBSCAN per vehicle over (x, y, velocity_scale * doppler residual): each vehicle keeps its
    main cluster. Not run when the learned membership has a context stage (it judges each point
    against its box's core itself); it still runs under the fixed frustum tests, without an
    ego-motion estimate, and with a membership model file that has no context stage.

    eps_m: DBSCAN radius in the scaled space, m; min_samples: DBSCAN core size.
    velocity_scale_s: metres per m/s of Doppler residual. A vehicle's points agree in
        residual to a few tenths of a m/s (more for near vehicles, whose velocity projects
        differently across their angular extent) but spread along up to 12 m of body, so
        the radius is wide in position and the residual is weighted up. Tuned on 100
        simulated mixed/hard frames: eps 6 m, scale 1 s gave point precision 0.94 and
        recall 0.98 (of points on detected moving vehicles).
    range_window_m: > 0: of a vehicle's cluster only the returns inside its densest range
        window this long stay (one body along the line of sight; range is the radar's precise
        coordinate).
    wheel_band_mps: > 0: points left out of their vehicle's main cluster rejoin it when near
        it and their residual lies between 0 and twice the cluster's (wheels), +- this. Off by
        default: on 200 wide hard scenes it cost 2 points of pair F1.
    """

    eps_m: float = 6.0
    min_samples: int = 1
    velocity_scale_s: float = 1.0
    parked_eps_m: float = 6.0
    range_window_m: float = 6.0
    wheel_band_mps: float = 0.0


@dataclass(frozen=True)
class BackgroundConfig:
    """Background sketch: DBSCAN over stationary points, then a capped voxel grid.

    eps_m / min_samples: DBSCAN in (x, y), m; points in no cluster (isolated clutter,
        ghosts) are dropped.
    voxel_m: voxel edge of the downsampling grid, m (points in a voxel -> their mean).
    max_points: cap on sketch points (most-supported voxels kept) so the frame stays 5-9 KB.
    """

    eps_m: float = 3.0
    min_samples: int = 2
    voxel_m: float = 0.5
    max_points: int = 600


@dataclass(frozen=True)
class InputConfig:
    """Plausibility limits on the inputs; rows beyond them are ignored, never an error.

    Points farther than max_range_m (any coordinate), with |doppler| above max_doppler_mps,
    or non-finite, are dropped; boxes with a non-finite corner, score or descriptor, a score
    outside 0-1, a depth beyond max_range_m or a corner beyond max_pixel (in the camera's
    pixels or in the canonical image the wire carries, shared.py) are not vehicles. The limits keep every product of `process_view` within the wire format
    (+-327 m, +-327 m/s, +-16383 px), so encoding it cannot fail.

    max_points: a frame with more usable points is thinned to this many, the same points
    whatever their order (a pseudo-random choice by their values): the CAV side's learned
    models read counts of returns (a box's, those the radar sees past it) fit on frames of at
    most about 400 (the simulator's wide and nominal families: 99th percentile 280-360), and a
    denser radar's frames read as false detections there. On copies of wide hard seeds 5 and 2
    with every return 8 times (1 deg and 0.1 m apart): success 0.340 / 0.365 without, 0.610 /
    0.600 at 400, 0.525 / 0.515 at 600 (0.715 / 0.695 as the scenes are); 4 times: 0.540 /
    0.585 -> 0.565 / 0.590. It also bounds the CAV side's time per frame. 0: no cap.
    unknown_depth_height_m: a box whose depth is missing (non-finite, 0 or negative: a detector
    without a depth output, or none for that box) is placed by the size prior instead, a
    vehicle this tall (m) at the box's pixel height, as the camera driver does without a road
    plane (drivers/camera/pipeline.py); 0: such boxes are not vehicles.
    """

    max_range_m: float = 300.0
    max_doppler_mps: float = 300.0
    max_pixel: float = 16000.0
    unknown_depth_height_m: float = 1.5
    max_points: int = 400


@dataclass(frozen=True)
class CavConfig:
    """Every CAV-side setting."""

    inputs: InputConfig = field(default_factory=InputConfig)
    radar: RadarAccuracyConfig = field(default_factory=RadarAccuracyConfig)
    egomotion: EgoMotionConfig = field(default_factory=EgoMotionConfig)
    separation: SeparationConfig = field(default_factory=SeparationConfig)
    plausibility: PlausibilityConfig = field(default_factory=PlausibilityConfig)
    clustering: ClusteringConfig = field(default_factory=ClusteringConfig)
    background: BackgroundConfig = field(default_factory=BackgroundConfig)

    def __post_init__(self) -> None:
        _check(self)

    @classmethod
    def from_dict(cls, data: dict) -> "CavConfig":
        """Build from {"egomotion": {...}, ...}; unknown keys raise ConfigError naming them."""
        if not isinstance(data, dict):
            raise ConfigError("cav: expected a mapping")
        sections = {f.name: f.type for f in dataclasses.fields(cls)}
        kwargs = {}
        for name, value in data.items():
            if name not in sections:
                raise ConfigError(f"cav.{name}: unknown section")
            sub_cls = _SECTIONS[name]
            if not isinstance(value, dict):
                raise ConfigError(f"cav.{name}: expected a mapping")
            known = {f.name: f for f in dataclasses.fields(sub_cls)}
            for key in value:
                if key not in known:
                    raise ConfigError(f"cav.{name}.{key}: unknown key")
            try:
                kwargs[name] = sub_cls(**{k: type(getattr(sub_cls(), k))(v) for k, v in value.items()})
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"cav.{name}: {exc}") from exc
        return cls(**kwargs)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


_SECTIONS = {"inputs": InputConfig, "radar": RadarAccuracyConfig, "egomotion": EgoMotionConfig, "separation": SeparationConfig,
             "plausibility": PlausibilityConfig,
             "clustering": ClusteringConfig, "background": BackgroundConfig}


def _check(cfg: CavConfig) -> None:
    """Cross-field checks: fail at start, naming the key."""
    positive = [("inputs.max_range_m", cfg.inputs.max_range_m),
                ("inputs.max_doppler_mps", cfg.inputs.max_doppler_mps),
                ("inputs.max_pixel", cfg.inputs.max_pixel),
                ("egomotion.threshold_mps", cfg.egomotion.threshold_mps),
                ("egomotion.max_speed_mps", cfg.egomotion.max_speed_mps),
                ("egomotion.edge_az_deg", cfg.egomotion.edge_az_deg),
                ("egomotion.hypotheses", cfg.egomotion.hypotheses),
                ("egomotion.min_pair_sin", cfg.egomotion.min_pair_sin),
                ("clustering.eps_m", cfg.clustering.eps_m),
                ("clustering.parked_eps_m", cfg.clustering.parked_eps_m),
                ("clustering.min_samples", cfg.clustering.min_samples),
                ("background.eps_m", cfg.background.eps_m),
                ("background.min_samples", cfg.background.min_samples),
                ("background.voxel_m", cfg.background.voxel_m),
                ("background.max_points", cfg.background.max_points),
                ("radar.channels_az", cfg.radar.channels_az), ("radar.channels_el", cfg.radar.channels_el),
                ("radar.bound_scale", cfg.radar.bound_scale), ("radar.doppler_mps", cfg.radar.doppler_mps)]
    non_negative = [("egomotion.threshold_growth_mps", cfg.egomotion.threshold_growth_mps),
                    ("egomotion.refine_iterations", cfg.egomotion.refine_iterations),
                    ("separation.delta_d_m", cfg.separation.delta_d_m),
                    ("separation.depth_rel", cfg.separation.depth_rel),
                    ("separation.moving_depth_rel", cfg.separation.moving_depth_rel),
                    ("separation.bearing_margin_deg", cfg.separation.bearing_margin_deg),
                    ("separation.bearing_margin_growth_deg", cfg.separation.bearing_margin_growth_deg),
                    ("separation.elevation_margin_deg", cfg.separation.elevation_margin_deg),
                    ("separation.edge_px", cfg.separation.edge_px),
                    ("separation.bearing_margin_sigma", cfg.separation.bearing_margin_sigma),
                    ("separation.glint_share", cfg.separation.glint_share),
                    ("separation.moving_ratio", cfg.separation.moving_ratio),
                    ("clustering.velocity_scale_s", cfg.clustering.velocity_scale_s),
                    ("egomotion.threshold_sigma", cfg.egomotion.threshold_sigma),
                    ("egomotion.threshold_floor_mps", cfg.egomotion.threshold_floor_mps),
                    ("radar.floor_az_deg", cfg.radar.floor_az_deg), ("radar.floor_el_deg", cfg.radar.floor_el_deg),
                    ("radar.glint_share", cfg.radar.glint_share),
                    ("inputs.unknown_depth_height_m", cfg.inputs.unknown_depth_height_m),
                    ("inputs.max_points", cfg.inputs.max_points)]
    for key, value in positive:
        if not value > 0:
            raise ConfigError(f"cav.{key}: must be > 0, got {value}")
    for key, value in non_negative:
        if not value >= 0:
            raise ConfigError(f"cav.{key}: must be >= 0, got {value}")
    if cfg.inputs.max_range_m > 327.0 or cfg.inputs.max_doppler_mps > 327.0 or cfg.inputs.max_pixel > 16383.0:
        raise ConfigError("cav.inputs: limits must stay within the wire format (327 m, 327 m/s, 16383 px)")
    if cfg.egomotion.min_points < 3:
        raise ConfigError(f"cav.egomotion.min_points: must be >= 3, got {cfg.egomotion.min_points}")
    if cfg.egomotion.min_inliers < 3:
        raise ConfigError(f"cav.egomotion.min_inliers: must be >= 3, got {cfg.egomotion.min_inliers}")
