"""Ego-side fusion of one own frame with one CAV frame: match, align, merge (DESIGN.md flow)."""

from __future__ import annotations

import contextlib
import copy
import time
from dataclasses import dataclass, field, replace

import numpy as np

from mmatch.ego.base import (AlignResult, MatchContext, MatchResult, far_side_centres,
                             velocity_heading_yaws, without_heading_prior)
from mmatch.ego.confidence import (Assessment, ConfidenceConfig, PairContext, assess_many, published_confidence,
                                   refusal, refused_probability, scaled_below, shared_view,
                                   single_pair_unconfirmed, tells_poses_apart, threshold, vehicle_distances,
                                   with_information)
from mmatch.ego.observations import observations_shared, observe
from mmatch.ego.rigid import near_transforms, rot2, se2_to_matrix
from mmatch.ego.descriptor_scale import RunningDescriptorScale
from mmatch.ego.registry import DEFAULT_ALIGNER, DEFAULT_MATCHER, get_aligner, get_matcher
from mmatch.ego.track import TrackConfig, Tracker
from mmatch.ego.track.filter import Candidate, pose_of, within_success
from mmatch.ego.track.objects import ObjectFrame, ObjectTrackConfig, ObjectTracker
from mmatch.ego.track.predict import Prediction
from mmatch.shared import SharedFrame, with_canonical_background

SOURCE_OWN, SOURCE_OTHER, SOURCE_BOTH = 0, 1, 2
OWN_EXTRA_HYPOTHESES = 3      # the matcher's other hypotheses the arbiter weighs beside MMatch's aligner
OWN_EXTRA_PER_DIRECTION = 1   # ... and its best one in each other direction class (see _other_hypotheses)


@dataclass(frozen=True)
class FusionConfig:
    """Which matcher and aligner run (by name); track: carry T_ego_cav across frames (off for
    independent scene files, on in the vehicle service); descriptor_calibration: keep a running
    descriptor scale for frames whose context gives none (off: 1, see EvalConfig); confidence:
    how sure an estimate must be to be fused (with tracking: the pose filter's confidence);
    extra_hypotheses: the matcher's best distinct other hypotheses the arbiter weighs beside
    the aligner's results, each with the pairs it implies (None: OWN_EXTRA_HYPOTHESES with
    MMatch's own aligner, none with any other, so that a peer aligner is judged on its own
    results); extra_per_direction: besides those, the matcher's best hypotheses of each other
    direction class (the aligner's yaw turned by 90, 180 and 270 deg, and its own yaw slid more
    than 5 m), this many of each (None: OWN_EXTRA_PER_DIRECTION with MMatch's own aligner, none
    with any other); objects: the fused object tracks (with tracking only, ego/track/objects.py)."""

    matcher: str = DEFAULT_MATCHER
    aligner: str = DEFAULT_ALIGNER
    track: TrackConfig = TrackConfig(max_age_s=0.0)
    descriptor_calibration: bool = False
    extra_hypotheses: int | None = None
    extra_per_direction: int | None = None
    confidence: ConfidenceConfig = ConfidenceConfig()
    objects: ObjectTrackConfig = ObjectTrackConfig()


@dataclass
class FusionResult:
    """status: "fused" | "single" (no CAV frame) | "no-estimate" (reason says why).

    A fused result from the track alone (nothing to match in this frame) has reason "tracked".

    T_ego_cav: float64 4x4 or None; pairs: int32 (P, 2) (own vehicle, other vehicle);
    objects: float32 (O, 4) x, y (Ego radar frame, m), source (0 own, 1 other, 2 both),
    vehicle index (own index for 0 and 2, other index for 1); timings: ms per stage.

    How sure it is (DESIGN.md eval output): confidence is the probability (0-1) that the
    estimate lies within 2 m / 5 deg of the truth (NaN when there is no estimate);
    covariance: float64 (3, 3) of (x m, y m, yaw rad) in the Ego radar frame, or None;
    ambiguity: the best distinct alternative's score relative to the chosen one (0: none,
    1: as good), NaN when unknown. An estimate whose confidence is below the configured
    threshold is refused: status "no-estimate", T_ego_cav None, the reason what weighs most
    against it, our own objects only; its pairs (the matcher's best guess of the vehicles both
    see), confidence, covariance and evidence stay.
    evidence: the features behind the confidence (see ego/confidence.py); refused_T: the
    estimate that was refused (for evaluation only; never publish it); candidates: every
    transform the arbiter weighed with its Assessment (for evaluation and fitting).
    """

    status: str
    reason: str = ""
    T_ego_cav: np.ndarray | None = None
    pairs: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))
    objects: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))
    timings: dict = field(default_factory=dict)
    confidence: float = float("nan")
    covariance: np.ndarray | None = None
    ambiguity: float = float("nan")
    evidence: dict = field(default_factory=dict)
    refused_T: np.ndarray | None = None
    candidates: list = field(default_factory=list)


class Fuser:
    """Holds the chosen matcher and aligner; call `fuse` per frame.

    With tracking (config.track.max_age_s > 0) each CAV's transform is filtered over time
    (ego/track/): the prediction seeds the matcher, every candidate the arbiter weighed updates
    the filter, and the filter's best hypothesis is what is published, with the filter's
    covariance and confidence; `track_objects` then keeps the fused objects' tracks (ids,
    velocities, covariances). Without tracking each frame stands alone."""

    def __init__(self, config: FusionConfig = FusionConfig()) -> None:
        self.config = config
        self.matcher = get_matcher(config.matcher)
        self.aligner = get_aligner(config.aligner)
        self.tracker = Tracker(config.track)
        self.objects = ObjectTracker(config.objects) if self.tracker.enabled else None
        self.descriptor_scale = RunningDescriptorScale()
        self._scorer = get_matcher("consensus")
        self._pairs_from_transform = bool(getattr(self.matcher, "pairs_from_transform", False))
        # RM-net's pair scores are confidence evidence whatever the matcher: the matcher's own
        # network when it has one (its scores are computed once per fusion), else the packaged one
        self._pair_scorer = getattr(self.matcher, "rmnet", None) or \
            (self.matcher if hasattr(self.matcher, "probabilities") else None)
        # ... and the pairs that network assigns under each candidate are evidence too: with a
        # matcher whose pairs under a transform are that assignment, the winner's are at hand
        self._pairs_by_rmnet = self._pairs_from_transform and bool(getattr(self.matcher, "pairs_by_rmnet", False))
        self._threshold = threshold(config.confidence)
        self._threshold_no_heading = threshold(config.confidence, heading=False)
        self._track_threshold = threshold(config.confidence, tracked=True)
        self._extra = config.extra_hypotheses if config.extra_hypotheses is not None else \
            (OWN_EXTRA_HYPOTHESES if config.aligner == DEFAULT_ALIGNER else 0)
        self._per_direction = config.extra_per_direction if config.extra_per_direction is not None else \
            (OWN_EXTRA_PER_DIRECTION if config.aligner == DEFAULT_ALIGNER else 0)
        self._deferred: list[tuple[SharedFrame, SharedFrame, MatchContext | None, Prediction]] = []

    def fuse(self, own: SharedFrame, other: SharedFrame | None,
             context: MatchContext | None = None) -> FusionResult:
        own_objs = _objects(far_side_centres(own), SOURCE_OWN)
        if other is None:
            return FusionResult("single", "no CAV frame", objects=own_objs)
        own, other = with_canonical_background(own), with_canonical_background(other)
        self.run_deferred(other.sender)          # this CAV's track must have seen its search
        pred = self.tracker.predict(own, other)
        return self._run(own, other, context, pred, own_objs, defer=self.config.track.defer_search)

    def run_deferred(self, sender: str | None = None) -> int:
        """Run the full searches that fusion deferred (TrackConfig.defer_search), of one CAV or
        of all (None); returns how many. The vehicle service calls this once a frame's results
        are published; `fuse` calls it first for its CAV, so a caller that never does gets the
        same results, only later (and a second CAV's fusion never waits for the first's)."""
        mine = [sender is None or other.sender == sender for _, other, _, _ in self._deferred]
        done = [d for d, m in zip(self._deferred, mine) if m]
        self._deferred = [d for d, m in zip(self._deferred, mine) if not m]
        for own, other, context, pred in done:
            self._run(own, other, context, pred, _objects(far_side_centres(own), SOURCE_OWN), defer=False)
        return len(done)

    def _run(self, own: SharedFrame, other: SharedFrame, context: MatchContext | None, pred: Prediction,
             own_objs: np.ndarray, defer: bool) -> FusionResult:
        with observations_shared(), (without_heading_prior() if pred.manoeuvre else contextlib.nullcontext()):
            # a vehicle turning (manoeuvre): its velocity tells no road direction
            return self._fuse_predicted(own, other, context, pred, own_objs, defer)

    def _fuse_predicted(self, own: SharedFrame, other: SharedFrame, context: MatchContext | None,
                        pred: Prediction, own_objs: np.ndarray, defer: bool = False) -> FusionResult:
        """`fuse` once the track (if any) is predicted to this frame pair; defer: a regular full
        search of a believed track is left for `run_deferred` (this frame refines the prediction)."""
        quick = pred.prior_T is not None and self.tracker.tracking_only(pred)
        no_vehicles = own.num_vehicles == 0 or other.num_vehicles == 0
        if defer and not quick and not no_vehicles and pred.prior_T is not None and self.tracker.search_due(pred):
            # the search starts from this prediction, not from the refinement committed below
            self._deferred.append((own, other, context, copy.deepcopy(pred)))
            quick = True
        # a full search does not see the track, so its candidates are evidence of their own;
        # a frame with nothing to match refines the prediction on the backgrounds
        predicted = pred.prior_T if quick or no_vehicles else None
        t0 = time.perf_counter()
        if no_vehicles:
            if predicted is None:
                reason = "no vehicles in " + ("the own frame" if own.num_vehicles == 0 else "the CAV frame")
                if pred.track is not None:          # the track goes on without this frame's evidence
                    return self._tracked(own, other, pred, own_objs, [], MatchResult(), {}, False,
                                         reason)
                return FusionResult("no-estimate", reason, objects=own_objs)
            match = MatchResult()
        else:
            ctx = context or MatchContext()
            if ctx.descriptor_scale is None:
                scale = self.descriptor_scale.update(own.vehicle_features, other.vehicle_features) \
                    if self.config.descriptor_calibration else 1.0
                ctx = replace(ctx, descriptor_scale=scale)
            match = self.matcher(own, other, replace(ctx, prior_T=predicted, prior_only=quick))
        tracked = match.T_hint is None and len(match.pairs) == 0 and predicted is not None
        if tracked:
            match = replace(match, T_hint=predicted)
        t1 = time.perf_counter()
        if quick and match.T_hint is not None:
            # a tracking frame: the matcher refined the prediction on vehicles, background
            # and heading already; the aligner's second pass would redo the same fit
            aligned = AlignResult(match.T_hint)
        else:
            aligned = self.aligner(own, other, match)
        t2 = time.perf_counter()
        timings = {"matching": (t1 - t0) * 1e3, "alignment": (t2 - t1) * 1e3}
        if aligned.T is None:
            if self.tracker.enabled:
                return self._tracked(own, other, pred, own_objs, [], match, timings,
                                     predicted is None, aligned.reason)
            return FusionResult("no-estimate", aligned.reason, pairs=match.pairs, objects=own_objs,
                                timings=timings)
        T, a, cands, pairs = self._arbitrate(own, other, match, aligned)
        heading = velocity_heading_yaws(own, other) is not None
        if hasattr(self.aligner, "polish"):
            # the chosen transform, once rated, refined with what only it implies (the vehicles'
            # sightings of each other: ego/align/constrained.py), its covariance with what they
            # add; the tracker measures it too
            T_chosen, (T, info) = T, self.aligner.polish(own, other, pairs, T, match.descriptor_scale, quick)
            if info is not None:
                a = replace(a, covariance=with_information(a.covariance, info, self.config.confidence, heading))
            cands = [(T, a) if Tc is T_chosen else (Tc, ac) for Tc, ac in cands]
        match = replace(match, pairs=pairs)
        timings["confidence"] = (time.perf_counter() - t2) * 1e3
        if self.tracker.enabled:
            return self._tracked(own, other, pred, own_objs, cands, match, timings,
                                 predicted is None, a.reason, (T, a), heading)
        ccfg = self.config.confidence
        thr = self._threshold if heading else self._threshold_no_heading
        why = refusal(a.confidence, a.features, thr, ccfg, len(match.pairs))
        # published with the model's calibration; the gates read the raw probability (the same
        # decisions, ego/confidence.py `ProbabilityModel.published`); a frame another gate
        # refused publishes below the threshold (`refused_probability`)
        sure = dict(confidence=published_confidence(refused_probability(a.confidence, why, thr, ccfg), ccfg, heading),
                    covariance=a.covariance, ambiguity=a.ambiguity, evidence=a.features, candidates=cands)
        if why is not None:
            # not sure enough, the matcher's own evidence prefers a distinct alternative (two
            # judges disagree: ambiguous), or one unconfirmed pair carries it; the vehicles both
            # probably see stay reported (with the estimate's confidence); the objects are not
            # merged without a transform
            reason = a.reason if why == "threshold" else why
            return FusionResult("no-estimate", reason, pairs=match.pairs, objects=own_objs,
                                timings=timings, refused_T=T, **sure)
        return FusionResult("fused", "", T, match.pairs, merge_objects(own, other, T, match.pairs), timings, **sure)

    def track_objects(self, own: SharedFrame, fused: list[tuple[SharedFrame, FusionResult]]) -> ObjectFrame | None:
        """The object tracks after this Ego frame: `own` and every CAV frame fused with it this
        frame with its result (status "fused"); None without tracking. Call once per Ego frame,
        after `fuse` for each CAV (the vehicle service does; so does `mmatch eval --sequences`).

        The Ego's yaw rate is the pose filter's (best hypothesis of the first fused CAV) when that
        knows it to `objects.own_yaw_rate_sigma` (rad/s), else 0: the relative pose tells the two
        vehicles' yaw rates apart only loosely, and a wrong one moves far objects sideways."""
        if self.objects is None:
            return None
        views, yaw_rate = [], 0.0
        for other, res in fused:
            if res.status != "fused" or res.T_ego_cav is None:
                continue
            views.append((other, res.T_ego_cav, res.covariance, res.pairs))
            tr = self.tracker.track(other.sender)
            best = tr.best() if tr is not None else None
            if len(views) == 1 and best is not None and best.P[3, 3] <= self.config.objects.own_yaw_rate_sigma ** 2:
                yaw_rate = float(best.x[3])
        return self.objects.step(own, views, yaw_rate)

    def _tracked(self, own: SharedFrame, other: SharedFrame, pred: Prediction, own_objs: np.ndarray,
                 cands: list, match: MatchResult, timings: dict, full_search: bool, reason: str,
                 chosen: tuple | None = None, heading: bool = True) -> FusionResult:
        """The pose filter's answer for this frame: every candidate the arbiter weighed is a
        measurement (ego/track/filter.py; the chosen one, `chosen` (T, Assessment), as
        `_measured_confidence` says, heading: the frame pair has a heading prior; own_objs: the
        Ego's own objects, published whatever the answer); the best
        hypothesis is published when its confidence reaches the threshold. Pairs: with a matcher that says `pairs_from_transform`, its
        assignment under the published transform, as without tracking (30 drives of seed 500,
        default matcher: tracked pair F1 0.840 -> 0.856); otherwise the matcher's when its choice
        falls in that hypothesis, else the vehicles the hypothesis lays on each other."""
        t0 = time.perf_counter()
        candidates = []
        for Tc, ac in cands:
            is_chosen = chosen is not None and ac is chosen[1]
            p = self._measured_confidence(ac, heading) if is_chosen else ac.confidence
            p = float(np.nan_to_num(p))
            candidates.append(Candidate(pose_of(Tc), ac.covariance, p,
                                        pred.settling or tells_poses_apart(ac.features, p)))
        hyp, hit = self.tracker.commit(own, other, pred, candidates, full_search, self._shared_view(own, other, pred))
        timings = dict(timings, track=(time.perf_counter() - t0) * 1e3)
        if hyp is None:
            return FusionResult("no-estimate", reason or "no track", objects=own_objs, timings=timings)
        T = hyp.T
        T[2, 3] = other.radar_height - own.radar_height
        cov = hyp.covariance(self.tracker.cfg.filter)
        # the probability that the hypothesis is the right one (its belief, built from calibrated
        # per-frame confidences) and, being it, lies within 2 m / 5 deg (its spread): confirmed
        # by this frame or carried by prediction alone. Its belief alone, on a frame that
        # confirmed it, published a right track drifting 23 deg at 0.89 (yaw sigma 6 deg)
        confidence = float(hyp.belief * within_success(cov))
        # ... and no surer than the established rival it overtook was wrong
        # (TrackConfig.rival_memory_s)
        ceiling = 1.0 - self.tracker.rival(other.sender, hyp)
        contested = confidence >= self._track_threshold > ceiling        # refused for that alone
        confidence = min(confidence, ceiling)
        pairs = np.asarray(match.pairs, np.int32).reshape(-1, 2)
        if self._pairs_from_transform:
            pairs = self.matcher.pairs_under(own, other, T[:2, :2], T[:2, 3], match.descriptor_scale)
        elif chosen is None or not self.tracker.agrees(hyp.T, chosen[0]):
            pairs = pairs_under(own, other, T)
        a = chosen[1] if chosen is not None else None
        sure = dict(confidence=confidence, covariance=cov, ambiguity=a.ambiguity if a is not None else float("nan"),
                    evidence=dict(a.features) if a is not None else {}, candidates=cands)
        tcfg = self.tracker.cfg
        young = hyp.hits < tcfg.min_hits and (tcfg.sure_at_once is None or confidence < tcfg.sure_at_once)
        thr = self._track_threshold
        if confidence < thr or young:
            reason = "unconfirmed" if young and confidence >= thr else \
                ("contested" if contested else (reason or "track not sure"))
            if reason == "unconfirmed" and thr > 0:   # below the threshold, as a single frame's gates publish
                sure["confidence"] = scaled_below(confidence, thr, tcfg.sure_at_once or 1.0)
            return FusionResult("no-estimate", reason, objects=own_objs, timings=timings,
                                refused_T=T, **sure)
        return FusionResult("fused", "" if hit else "tracked", T, pairs, merge_objects(own, other, T, pairs),
                            timings, **sure)

    def _measured_confidence(self, a: Assessment, heading: bool) -> float:
        """How sure the pose filter takes the frame's chosen estimate to be: its published
        (calibrated) confidence, as a single frame would publish it; the filter's other
        measurements, the candidates not chosen, keep the model's probability, which was fit on
        all of them. An estimate that one unconfirmed pair carries below the single-pair
        threshold, which a single frame refuses whatever its probability, keeps its raw one too:
        at its calibrated confidence a run of such frames held a wrong pose for a second on one
        drive of seed 800 (20 gross frames). With calibrated measurements and the track
        threshold 0.75 the tracker's tuning drives (seeds 400, 450, 460) went from success 0.757
        with 13 gross frames of 5400 to 0.809 with 6 (README, "Over time")."""
        ccfg = self.config.confidence
        if single_pair_unconfirmed(a.confidence, a.features, ccfg):
            return a.confidence
        return published_confidence(a.confidence, ccfg, heading)

    def _shared_view(self, own: SharedFrame, other: SharedFrame, pred: Prediction) -> list[tuple[float, float]] | None:
        """(expected, missed) vehicles of the shared view at each predicted hypothesis' pose."""
        hyps = pred.track.hypotheses if pred.track is not None else []
        if not hyps:
            return None
        x = np.array([h.x[:3] for h in hyps])
        cfg = self.config.confidence
        expected, missed = shared_view(observe(own, cfg.observation), observe(other, cfg.observation), rot2(x[:, 2]),
                                       x[:, :2], cfg)
        return list(zip(expected.tolist(), missed.tolist()))

    def _arbitrate(self, own: SharedFrame, other: SharedFrame, match: MatchResult, aligned: AlignResult):
        """The aligner's candidates, and the matcher's best distinct other hypotheses each with
        the pairs it implies, rated by the confidence model; the most probable one wins.

        Returns T (4x4), its Assessment, every candidate as (T, Assessment) for evaluation, and
        the winner's pairs. With a matcher that says `pairs_from_transform` the winner's pairs
        are the vehicles its transform lays onto each other (the matcher's `pairs_under`: its own
        final assignment without the road-speed veto) rather than the pairs the matcher kept under
        its own best hypothesis: the aligner's result moves from that hypothesis, and the veto,
        which helps choose among hypotheses, dropped true pairs under a known transform (its
        road-direction assumption fails at junctions and on noisy radial speeds). On 1000 wide
        hard scenes (seeds 5-9): pair F1 0.809 -> 0.835 (recall 0.794 -> 0.848, precision 0.824
        -> 0.823); the transforms are unchanged.
        """
        scale = match.descriptor_scale
        ctx = PairContext(own, other, self._scorer.scorer(own, other, scale), self.config.confidence,
                          self._pair_scorer, scale)
        if aligned.candidates is not None and len(aligned.candidates[0]):
            R, t = aligned.candidates
        else:
            R, t = aligned.T[None, :2, :2], aligned.T[None, :2, 3]
        dz = aligned.T[2, 3]
        n_aligned = len(R)
        pairs = [np.asarray(match.pairs, np.int32).reshape(-1, 2)] * n_aligned
        extra = _other_hypotheses(match, R, t, self._extra, self._per_direction)
        if extra:
            R = np.concatenate([R, np.stack([r for r, _ in extra])])
            t = np.concatenate([t, np.stack([x for _, x in extra])])
        d = vehicle_distances(ctx, R, t)                  # one table for the pairs and the evidence
        for h in range(n_aligned, len(R)):
            pairs.append(self._scorer.pairs_under(own, other, R[h], t[h], scale, (ctx.A, ctx.B),
                                                  d[h] if d is not None else None))
        rated = assess_many(ctx, R, t, pairs, match, d)
        Ts = [se2_to_matrix(R[h], t[h], dz) for h in range(len(R))]
        p = np.array([x.confidence if np.isnan(x.choice) else x.choice for x in rated])   # the chooser's score
        k = int(np.nanargmax(p)) if np.isfinite(p).any() else 0
        chosen = pairs[k]
        if self._pairs_by_rmnet and rated[k].rmnet_pairs is not None:
            chosen = rated[k].rmnet_pairs
        elif self._pairs_from_transform:
            chosen = self.matcher.pairs_under(own, other, R[k], t[k], scale, (ctx.A, ctx.B))
        return Ts[k], rated[k], list(zip(Ts, rated)), chosen


def fuse(own: SharedFrame, other: SharedFrame | None, config: FusionConfig | None = None) -> FusionResult:
    """One-shot fusion with a fresh Fuser (use a Fuser to keep the models loaded across frames)."""
    return Fuser(config or FusionConfig()).fuse(own, other)


def _objects(xy: np.ndarray, source: int) -> np.ndarray:
    n = len(xy)
    return np.column_stack([xy, np.full(n, source), np.arange(n)]).astype(np.float32).reshape(-1, 4)


def _other_hypotheses(match: MatchResult, R: np.ndarray, t: np.ndarray, n: int, per_direction: int = 0,
                      distinct_m: float = 1.5, distinct_deg: float = 3.0, slide_m: float = 5.0,
                      min_share: float = 0.6):
    """The matcher's n best-scored hypotheses not within distinct_m / distinct_deg of a candidate
    (R (K, 2, 2), t (K, 2)) or of each other, then the best of each other direction class until
    it has per_direction among them: (R (2, 2), t (2,)) each.

    Direction classes, against the first candidate (the aligner's choice): its yaw turned by 90,
    180 and 270 deg (to the nearest quarter turn), and its own yaw with the translation more than
    slide_m away. They are the mistakes a heading prior modulo 90 deg and a regular street allow
    (a flip, a crossing, a slide): the consensus score ranks such a rival below its own
    neighbours, so the n best alone rarely include it. The arbiter weighs each with evidence the
    score lacks (ego/confidence.py); with the truth among the candidates it picks it often
    (docs/method.md, "Which candidates the arbiter weighs"). Only rivals scoring at least min_share of
    the best hypothesis' score are weighed: each costs a confidence assessment (about 0.5 ms),
    and weaker ones are hardly ever chosen (on wide hard seeds 1, 3, 4, shares 0 / 0.5 / 0.6 /
    0.7 / 0.8 gave pair F1 0.933 / 0.933 / 0.934 / 0.934 / 0.931 and candidates grossly wrong
    0.115 / 0.113 / 0.113 / 0.115 / 0.117, 0.6 for about 1 ms less than 0)."""
    hyp = match.hypotheses
    if hyp is None or len(hyp.R) == 0 or (n <= 0 and per_direction <= 0) or len(R) == 0:
        return []
    yaw = np.arctan2(hyp.R[:, 1, 0], hyp.R[:, 0, 0])
    candidate_yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    # which hypotheses lie near a candidate, and near each other (the greedy choice reads these)
    near_candidate = near_transforms(yaw, hyp.t, candidate_yaw, t, distinct_m, distinct_deg).any(axis=1).tolist()
    near = near_transforms(yaw, hyp.t, yaw, hyp.t, distinct_m, distinct_deg).tolist()
    taken: list[int] = []

    def take_if_distinct(h: int) -> bool:
        if near_candidate[h] or any(near[h][g] for g in taken):
            return False
        taken.append(h)
        return True

    order = np.argsort(-np.asarray(hyp.score), kind="stable")
    for h in order:
        if len(taken) >= n:
            break
        take_if_distinct(int(h))
    if per_direction > 0:
        turn = (yaw - candidate_yaw[0] + np.pi) % (2 * np.pi) - np.pi
        quarter = np.round(turn / (np.pi / 2)).astype(int) % 4
        slid = (quarter == 0) & (np.linalg.norm(hyp.t - t[0], axis=1) > slide_m)
        score = np.asarray(hyp.score, np.float64)
        strong = score >= min_share * max(float(np.max(score)), 0.0)
        best = list(taken)
        for members in (slid, quarter == 1, quarter == 2, quarter == 3):
            kept = int(members[best].sum())                         # the n best may hold some already
            for h in order[(members & strong)[order]]:
                if kept >= per_direction:
                    break
                kept += take_if_distinct(int(h))
    return [(hyp.R[h], hyp.t[h]) for h in taken]


def pairs_under(own: SharedFrame, other: SharedFrame, T: np.ndarray, gate_m: float = 2.5) -> np.ndarray:
    """(P, 2) one-to-one pairs of vehicles that T (4x4) lays within gate_m of each other (nearest first)."""
    a = far_side_centres(own)
    b = far_side_centres(other) @ T[:2, :2].T + T[:2, 3]
    if len(a) == 0 or len(b) == 0:
        return np.zeros((0, 2), np.int32)
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    out = []
    for flat in np.argsort(d, axis=None):
        i, j = divmod(int(flat), d.shape[1])
        if d[i, j] > gate_m:
            break
        if all(i != p and j != q for p, q in out):
            out.append((i, j))
    return np.array(out, np.int32).reshape(-1, 2)


def merge_objects(own: SharedFrame, other: SharedFrame, T: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Both views' vehicles in the Ego frame; a matched pair becomes one object at their mean."""
    a = far_side_centres(own)
    b = far_side_centres(other) @ T[:2, :2].T + T[:2, 3]
    objs = _objects(a, SOURCE_OWN)
    if len(pairs):
        objs[pairs[:, 0], :2] = (a[pairs[:, 0]] + b[pairs[:, 1]]) / 2
        objs[pairs[:, 0], 2] = SOURCE_BOTH
    rest = np.setdiff1d(np.arange(len(b)), pairs[:, 1] if len(pairs) else [])
    return np.vstack([objs, _objects(b, SOURCE_OTHER)[rest]])
