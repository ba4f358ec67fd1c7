"""Carry T_ego_cav from frame to frame: one multi-hypothesis pose filter per CAV (ego/track/filter.py).

`Tracker.predict` moves a CAV's track to the new frame pair's capture stamps (both radars'
Doppler velocities and the filtered yaw rates); its best hypothesis seeds the matcher when
believed enough. Between full (global) searches the matcher only refines that prediction; a
full search comes back every `full_search_every` frames, when the track is lost, and right
after a tracking frame whose result did not fall in the track. `Tracker.commit` takes every
candidate transform the frame's arbiter weighed and returns the hypothesis to publish.

Frames: T maps CAV-radar coordinates into Ego-radar coordinates (DESIGN.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mmatch.ego.track.filter import (Candidate, FilterConfig, Hypothesis, PoseTrack, new_hypothesis, pose_of,
                                     predict as predict_hypothesis, step, velocity_of, wrap)
from mmatch.ego.track.odometry import OdometryConfig, rotation
from mmatch.shared import SharedFrame


# rad/s: no road vehicle turns faster (5 m/s on a 2.5 m radius); a sideways speed that implies
# more (a garbled or forged velocity) is capped there
MAX_YAW_RATE = 2.0
# the beliefs a track remembers for `TrackConfig.rival_memory_s` (up to max_hypotheses a frame):
# ample at 20 Hz, a bound when frames come far faster
MAX_BELIEF_RECORDS = 512


@dataclass(frozen=True)
class TrackConfig:
    """max_age_s: a track not updated for this long (either radar's clock) is dropped; 0: no
    tracking (every frame on its own). 0.5 s (2 s until 2026-12-07): frames lost for longer (the
    radio, a sensor restarting) may hide a whole turn, which neither the constant-yaw-rate
    prediction nor the manoeuvre test (a turn that ended shows no sideways velocity) sees; on ten
    drives each of seeds 500 and 600 with 1 s of frames removed, 2 s published 12 and 6 frames
    13-42 deg off at 0.62-0.99 after the gap, 0.5 s none (tracked success 0.757 -> 0.667, 0.810
    -> 0.780: the track starts again); widening the yaw and yaw rates by the time lost instead
    left 5 and 0 (0.698, 0.855). The drives without a gap track identically (seeds 400-900).
    full_search_every: frames between full searches while tracking (and only while the best
    hypothesis is believed at least quick_belief); agree_m / agree_deg: two transforms this close agree; prior_belief: a best hypothesis at least this believed seeds the matcher;
    min_hits: a hypothesis is published once this many frames have confirmed it (one
    frame's confident mistake is not, two agreeing frames are); sure_at_once: a hypothesis is
    also published at once when its confidence reaches this (0.9, chosen on the tuning drives
    of seeds 400, 450 and 460: young hypotheses at 0.75 / 0.85 / 0.9 / 0.95 or above were right
    in 77 / 73 / 68 / 52 of 5400 frames, with 1 / 0 / 0 / 0 gross and 2 / 2 / 2 / 1 moderately
    wrong, when a confirming frame published a track at its belief; since it is belief times
    spread, 0.9 against waiting is success 0.824 -> 0.834 there with 6 gross frames both);
    waiting for the second frame lost the first of nearly every drive; None: always wait);
    manoeuvre_deg: a radar whose velocity direction in its own frame lies this far from where it
    pointed before the turn (while faster than manoeuvre_speed_mps) is turning (a radar ahead of
    the rear axle sees its velocity swing sideways by yaw rate x lever arm, and hold that offset
    through a steady turn); every such frame searches globally without the road-direction prior
    (a turning vehicle's velocity tells no road), and where the direction changed since the last
    full search (a turn begins or ends) that vehicle's yaw rate is made uncertain by
    manoeuvre_yaw_rate_sigma (rad/s): the constant-yaw-rate prediction no longer holds there.
    Until 2026-12-06 (late) one reference, reset by every full search, served both, so only a
    turn's first frames searched: through a steady turn the track then kept its yaw while the
    truth turned 1.5-1.8 deg a frame (README, Over time); manoeuvre_max_s: a turn this long (s)
    ends, its direction then the new reference (a drive that began in a turn, a long curve);
    manoeuvre_hold_s: while a radar turns or its yaw rate changes, and for this long (s) after,
    every candidate weighs for or against the hypothesis it lands in, also one whose evidence
    cannot tell poses apart (filter.Candidate.informative; `Prediction.settling`): a turn whose
    end the manoeuvre test calls early leaves the track a yaw rate that refinements starting at
    its prediction follow instead of correcting (a drive of seed 500 drifted 1.6 deg a frame,
    published at 0.8-0.9, when such frames only aged the track); 1 s and 2 s tracked alike on
    the tuning drives, 1 s kept;
    defer_search: the regular full search of a believed track runs after the frame's result
    (`Fuser.run_deferred`, which the vehicle service calls once it has published): that frame
    publishes the refined prediction as any tracking frame, and the search's candidates then
    update the track from the same prediction (in place of that refinement), so the next
    frame sees what the search found and no frame waits for it;
    lever_arm_m: how far ahead of its vehicle's rear axle a radar sits, until learnt (m; a car's
    front radar sits 3.2-3.9 m ahead, the simulator's 1.9-4.4 m ahead of the vehicle's centre,
    the point its kinematics move without slip); a turning radar moves sideways at yaw rate x
    lever arm, so on each frame of a turn its velocity's offset from where it pointed before
    the turn bounds that vehicle's yaw rate: v sin(offset) / lever arm, within lever_arm_spread
    of it (relative, 1 sigma, plus 0.05 rad/s), taken by a hypothesis whose yaw rate is less
    sure than that. Each radar's own lever arm is learnt from the frames of a turn whose track
    knows its yaw rate to lever_arm_learn_within (relative; the bound alone never does:
    candidates must measure the turn), sideways speed / yaw rate, and then bounds its later
    frames within lever_arm_learnt_spread. Without the bound a track that saw no vehicle in
    common through a turn coasted at the yaw rate it had, 1.5-2 deg a frame off (README, Over
    time); 3.0 m and the spreads are not fit to the drives (the simulator's cars sit near 2.1 m:
    learning is what closes the gap); lever_arm_m 0: off;
    rival_memory_s, rival_hits, rival_belief: a hypothesis is published at no more than 1 - b
    for rival_memory_s after another one that frames had confirmed rival_hits times was
    believed b >= rival_belief (its evidence was of the same kind and it was wrong, or this
    one is: frames of one drive are not independent, so a belief that swung once can swing
    back). Without it a track that had lost a right pose to a slide onto the car in front of
    the CAV, or a 180 deg flip, published it at 0.73-0.97 the frame it took over (README, Over
    time); 1 s, 3 hits and 0.5 chosen on the tuning drives (seeds 400, 450, 460); rival_memory_s
    0: off;
    odometry: each radar's rotation between its consecutive frames, from its stationary
    background (ego/track/odometry.py), taken as an observation of that vehicle's yaw rate
    (rotation / dt, a scalar Kalman update of every hypothesis before it is moved); None: off.
    Without it a turn no candidate measured was tracked at the lever arm's bound: the drives of
    seed 500 at 10 Hz published a CAV turning at 45 deg/s at 30 deg/s, 14-18 deg off at
    0.71-0.88 (README, Over time);
    filter: the pose filter's noise, gates and belief (ego/track/filter.py)."""

    max_age_s: float = 0.5
    full_search_every: int = 10
    defer_search: bool = True
    quick_belief: float = 0.9
    quick_fit: float = 0.3
    agree_m: float = 2.0
    agree_deg: float = 5.0
    prior_belief: float = 0.3
    min_hits: int = 2
    sure_at_once: float | None = 0.9
    manoeuvre_deg: float = 3.0
    manoeuvre_speed_mps: float = 2.0
    manoeuvre_yaw_rate_sigma: float = 0.4
    manoeuvre_max_s: float = 5.0
    manoeuvre_hold_s: float = 1.0
    lever_arm_m: float = 3.0
    lever_arm_spread: float = 0.5
    lever_arm_learn_within: float = 0.2
    lever_arm_learnt_spread: float = 0.25
    rival_memory_s: float = 1.0
    rival_hits: int = 3
    rival_belief: float = 0.5
    odometry: OdometryConfig | None = field(default_factory=OdometryConfig)
    filter: FilterConfig = field(default_factory=FilterConfig)


@dataclass
class Prediction:
    """A CAV's track moved to a new frame pair (not yet committed): the track (or None when
    there was none), the elapsed times (s) and the prior for the matcher (4x4 or None);
    manoeuvre: a radar is turning or its yaw rate changing (`Tracker._manoeuvres`); turning
    (2,): which of the Ego's and the CAV's radars is turning (`commit` keeps their references);
    settling: a manoeuvre runs or ended less than TrackConfig.manoeuvre_hold_s ago."""

    track: PoseTrack | None
    dt_own: float
    dt_other: float
    prior_T: np.ndarray | None
    manoeuvre: bool = False
    turning: np.ndarray = field(default_factory=lambda: np.zeros(2, bool))
    settling: bool = False


class Tracker:
    """One PoseTrack per CAV (by sender id)."""

    def __init__(self, config: TrackConfig = TrackConfig()) -> None:
        self.cfg = config
        self._tracks: dict[str, PoseTrack] = {}

    @property
    def enabled(self) -> bool:
        return self.cfg.max_age_s > 0

    def track(self, sender: str) -> PoseTrack | None:
        """The committed track of a CAV (for inspection)."""
        return self._tracks.get(sender)

    def predict(self, own: SharedFrame, other: SharedFrame) -> Prediction:
        """The sender's track at the two frames' stamps (a copy; `commit` keeps it)."""
        tr = self._tracks.get(other.sender) if self.enabled else None
        if tr is None:
            return Prediction(None, 0.0, 0.0, None)
        dt_own, dt_other = float(own.stamp) - tr.own_stamp, float(other.stamp) - tr.other_stamp
        if not (abs(dt_own) <= self.cfg.max_age_s and abs(dt_other) <= self.cfg.max_age_s):
            del self._tracks[other.sender]
            return Prediction(None, 0.0, 0.0, None)
        v_own = (tr.v_own + velocity_of(own)) / 2
        v_other = (tr.v_other + velocity_of(other)) / 2
        rates = self._odometry(tr, own, other, dt_own, dt_other)
        hyps = [predict_hypothesis(_with_rates(h, rates, self.cfg.manoeuvre_yaw_rate_sigma), v_own, v_other,
                                    dt_own, dt_other, self.cfg.filter)
                for h in tr.hypotheses]
        moved = PoseTrack(hyps, float(own.stamp), float(other.stamp), velocity_of(own), velocity_of(other),
                          tr.since_full, tr.frames, dict(tr.extra), list(tr.beliefs))
        turning, changing = self._manoeuvres(moved)
        manoeuvre = bool(turning.any() or changing.any())
        if manoeuvre:
            moved.extra["last_manoeuvre"] = float(own.stamp)
        since = float(own.stamp) - moved.extra.get("last_manoeuvre", -np.inf)
        settling = since <= self.cfg.manoeuvre_hold_s
        for h in hyps:
            for k in np.flatnonzero(changing):
                h.P[3 + k, 3 + k] += self.cfg.manoeuvre_yaw_rate_sigma ** 2
        self._turn_rates(moved, turning)
        best = moved.best()
        prior = best.T if best is not None and best.belief >= self.cfg.prior_belief else None
        return Prediction(moved, dt_own, dt_other, prior, manoeuvre, turning, settling)

    def _odometry(self, track: PoseTrack, own: SharedFrame, other: SharedFrame, dt_own: float,
                  dt_other: float) -> list[tuple[float, float] | None]:
        """Each radar's yaw rate (rad/s) and its variance over the time since the track's last
        frame, from its background then and now (`TrackConfig.odometry`; the search centred on
        the best hypothesis' rate), or None where it cannot be measured."""
        prev = track.extra.get("backgrounds")
        if self.cfg.odometry is None or prev is None:
            return [None, None]
        best = track.best()
        out: list[tuple[float, float] | None] = []
        for k, (frame, v_prev, dt) in enumerate(((own, track.v_own, dt_own), (other, track.v_other, dt_other))):
            guess = float(best.x[3 + k]) * dt if best is not None else 0.0
            known = bool(np.all(np.isfinite(np.asarray(frame.ego_velocity, float))))   # else no translation
            r = rotation(prev[k], frame.background, v_prev, velocity_of(frame), dt, guess, self.cfg.odometry) \
                if dt > 0 and known else None
            out.append(None if r is None else (r[0] / dt, (r[1] / dt) ** 2))
        return out

    def _turn_rates(self, track: PoseTrack, turning: np.ndarray) -> None:
        """Bound each turning radar's yaw rate (track state 3 + k, rad/s, counter-clockwise) by
        its sideways velocity (TrackConfig.lever_arm_m): a scalar Kalman update of each
        hypothesis whose yaw rate is less certain than the bound (the lever arm's error is the
        same on every frame of a turn: the bound is not taken again once the rate is surer, and
        a rate the candidates have measured since is kept). A hypothesis no frame has confirmed
        yet, whose yaw rates are a guess of none, takes the bound."""
        if self.cfg.lever_arm_m <= 0 or not turning.any():
            return
        lateral = _sideways(track)
        learnt = np.asarray(track.extra.get("lever", np.full(2, np.nan)), float)
        for k in np.flatnonzero(turning):
            known = np.isfinite(learnt[k])
            rate = float(np.clip(lateral[k] / (learnt[k] if known else self.cfg.lever_arm_m),
                                 -MAX_YAW_RATE, MAX_YAW_RATE))
            spread = self.cfg.lever_arm_learnt_spread if known else self.cfg.lever_arm_spread
            var = (spread * abs(rate) + 0.05) ** 2
            i = 3 + k
            for h in track.hypotheses:
                if h.hits <= 1:
                    h.x[i], h.P[i, :], h.P[:, i] = rate, 0.0, 0.0
                    h.P[i, i] = var
                elif h.P[i, i] > var:
                    gain = h.P[:, i] / (h.P[i, i] + var)
                    h.x = h.x + gain * (rate - h.x[i])
                    h.P = h.P - np.outer(gain, h.P[i])

    def _learn_lever_arms(self, track: PoseTrack, turning: np.ndarray) -> None:
        """Learn each turning radar's lever arm (m) from a turn its track measures: where the best
        hypothesis knows that radar's yaw rate to lever_arm_learn_within of itself (candidates,
        not the bound alone, can make it that sure), sideways velocity / yaw rate, averaged over
        the frames (track.extra["lever"]); a vehicle's lever arm does not change."""
        best = track.best()
        if best is None or not turning.any():
            return
        lateral = _sideways(track)
        lever = np.array(track.extra.get("lever", np.full(2, np.nan)), float)
        for k in np.flatnonzero(turning):
            rate, sd = best.x[3 + k], np.sqrt(best.P[3 + k, 3 + k])
            sure = abs(rate) >= 0.1 and sd <= self.cfg.lever_arm_learn_within * abs(rate)
            if not (sure and lateral[k] * rate > 0):         # a NaN sideways speed: nothing
                continue
            arm = float(np.clip(lateral[k] / rate, 1.0, 6.0))
            lever[k] = arm if not np.isfinite(lever[k]) else 0.8 * lever[k] + 0.2 * arm
        track.extra["lever"] = lever

    def _manoeuvres(self, track: PoseTrack) -> tuple[np.ndarray, np.ndarray]:
        """(turning (2,), changing (2,)) bool for the Ego's and the CAV's radar. A radar ahead of
        the rear axle sees its velocity swing sideways by yaw rate x lever arm when a turn begins,
        hold that offset through a steady turn and swing back when it ends. Turning: its
        velocity points more than manoeuvre_deg away, in its own frame, from where it pointed
        before the turn (track.extra["straight"], which a full search sets for a radar that is
        not turning); the whole turn counts, and one longer than manoeuvre_max_s (the Ego's
        clock) ends, its direction then the new reference (a drive that began in a turn, a long
        curve). Changing: it turned that far since the last full search (track.extra["heading"]):
        the yaw rate is changing."""
        now = _headings(track)
        fast = _speeds(track) >= self.cfg.manoeuvre_speed_mps

        def away(ref: np.ndarray | None) -> np.ndarray:
            if ref is None:
                return np.zeros(2, bool)
            gap = np.degrees(np.abs(wrap(now - ref)))
            return fast & np.isfinite(ref) & (gap > self.cfg.manoeuvre_deg)

        changing = away(track.extra.get("heading"))
        straight = track.extra.get("straight")
        turning = away(straight)
        since = np.asarray(track.extra.get("turning_since", np.full(2, np.nan)), float)
        since = np.where(turning, np.where(np.isfinite(since), since, track.own_stamp), np.nan)
        expired = turning & (track.own_stamp - since > self.cfg.manoeuvre_max_s)
        if expired.any():
            track.extra["straight"] = np.where(expired, now, straight)
            turning, since = turning & ~expired, np.where(expired, np.nan, since)
        track.extra["turning_since"] = since
        return turning, changing

    def agrees(self, T: np.ndarray, other_T: np.ndarray | None) -> bool:
        """Whether two transforms (4x4) lie within agree_m / agree_deg of each other."""
        if other_T is None:
            return False
        d = np.linalg.norm(T[:2, 3] - other_T[:2, 3])
        yaw = np.degrees(abs(wrap(np.arctan2(T[1, 0], T[0, 0])
                                  - np.arctan2(other_T[1, 0], other_T[0, 0]))))
        return bool(d <= self.cfg.agree_m and yaw <= self.cfg.agree_deg)

    def tracking_only(self, pred: Prediction) -> bool:
        """Whether this frame may skip the global search and only refine the prediction: a
        believed track, a full search less than full_search_every frames ago, and the last
        tracking frame fell in the track."""
        tr = self._believed(pred)
        return tr is not None and 0 < tr.since_full < self.cfg.full_search_every

    def search_due(self, pred: Prediction) -> bool:
        """Whether this frame is a believed track's regular full search (`tracking_only` but for
        the full_search_every frames since the last one): the one kind of search that may be
        deferred (TrackConfig.defer_search)."""
        tr = self._believed(pred)
        return tr is not None and tr.since_full >= self.cfg.full_search_every

    def _believed(self, pred: Prediction) -> PoseTrack | None:
        """The predicted track when its best hypothesis is believed at least quick_belief and
        no radar is manoeuvring, else None."""
        tr = pred.track
        best = tr.best() if tr is not None else None
        ok = best is not None and best.belief >= self.cfg.quick_belief and not pred.manoeuvre
        return tr if ok else None

    def commit(self, own: SharedFrame, other: SharedFrame, pred: Prediction, candidates: list[Candidate],
               full_search: bool, view: list[tuple[float, float]] | None = None) -> tuple[Hypothesis | None, bool]:
        """Update the predicted track with the frame's candidates and keep it.

        Returns the best hypothesis (None: no track) and whether it took a measurement of this
        frame. full_search: the candidates come from a search that did not know the track
        (evidence for and against its hypotheses); else they refine its prediction. A
        tracking frame whose candidates missed the best hypothesis makes the next frame
        search globally, as does one whose best fit is less sure than quick_fit. view: per
        predicted hypothesis, the shared-view evidence at its pose (filter.step).
        """
        if not self.enabled:
            return None, False
        track = pred.track
        if track is None:
            track = PoseTrack([], float(own.stamp), float(other.stamp), velocity_of(own), velocity_of(other))
        hit = step(track, candidates, max(pred.dt_own, 0.0), self.cfg.filter, independent=full_search, view=view)
        track.frames += 1
        track.extra["backgrounds"] = (own.background[:, :2].copy(), other.background[:, :2].copy())
        self._remember_beliefs(track, float(own.stamp))
        if hit:
            self._learn_lever_arms(track, pred.turning)
        if full_search:
            track.since_full = 1
            now = _headings(track)
            track.extra["heading"] = now
            # a turning radar keeps the direction it had before the turn as its reference
            ref = track.extra.get("straight")
            track.extra["straight"] = now if ref is None else np.where(pred.turning, ref, now)
        elif hit and max((c.p for c in candidates), default=0.0) >= self.cfg.quick_fit:
            track.since_full += 1
        else:
            track.since_full = 0
        if not track.hypotheses:
            self._tracks.pop(other.sender, None)
            return None, False
        self._tracks[other.sender] = track
        return track.best(), hit

    def _remember_beliefs(self, track: PoseTrack, stamp: float) -> None:
        """Keep the beliefs of the track's established hypotheses over the last rival_memory_s."""
        cfg = self.cfg
        # a stamp ahead of this frame's (a clock stepped back) is not recent: it would never age
        recent = [r for r in track.beliefs if stamp - cfg.rival_memory_s <= r[0] <= stamp]
        recent += [(stamp, h.uid, h.belief) for h in track.hypotheses
                   if h.hits >= cfg.rival_hits and h.belief >= cfg.rival_belief]
        track.beliefs = recent[-MAX_BELIEF_RECORDS:]

    def rival(self, sender: str, hyp: Hypothesis) -> float:
        """The highest belief another established hypothesis of this CAV's track had over the
        last rival_memory_s (0: none; see TrackConfig): `hyp` is published at no more than
        1 - it."""
        track = self._tracks.get(sender)
        if track is None or self.cfg.rival_memory_s <= 0:
            return 0.0
        return max((b for _, uid, b in track.beliefs if uid != hyp.uid), default=0.0)

    def force(self, own: SharedFrame, other: SharedFrame, T: np.ndarray, belief: float = 0.99) -> None:
        """Replace a CAV's track by a single hypothesis at T (4x4) believed `belief` (tests and
        fault injection: a wrong track that the filter must leave)."""
        h = new_hypothesis(pose_of(T), np.diag([0.1, 0.1, np.radians(0.5) ** 2]), belief, self.cfg.filter)
        self._tracks[other.sender] = PoseTrack([h], float(own.stamp), float(other.stamp), velocity_of(own),
                                               velocity_of(other), since_full=1)

    def reset(self, sender: str | None = None) -> None:
        """Forget one sender's track, or all."""
        if sender is None:
            self._tracks.clear()
        else:
            self._tracks.pop(sender, None)


def _with_rates(h: Hypothesis, rates: list[tuple[float, float] | None], onset_sigma: float) -> Hypothesis:
    """A copy of h with each radar's yaw rate (state 3 + k) updated by a measured rate and
    variance (None: not measured): a scalar Kalman update, after widening the rate by
    onset_sigma (rad/s) where the measurement lies beyond 3 sigma of it (a turn begins or ends
    that nothing else noticed: a radar over its vehicle's turning centre does not move sideways)."""
    if all(r is None for r in rates):
        return h
    out = h.copy()
    for k, r in enumerate(rates):
        if r is None:
            continue
        rate, var = float(np.clip(r[0], -MAX_YAW_RATE, MAX_YAW_RATE)), r[1]
        i = 3 + k
        if (rate - out.x[i]) ** 2 > 9.0 * (out.P[i, i] + var):
            out.P[i, i] += onset_sigma ** 2
        gain = out.P[:, i] / (out.P[i, i] + var)
        out.x = out.x + gain * (rate - out.x[i])
        out.P = out.P - np.outer(gain, out.P[i])
    return out


def _sideways(track: PoseTrack) -> np.ndarray:
    """(2,) each radar's sideways speed (m/s, positive to the left) off the direction it pointed
    before its turn (track.extra["straight"]; NaN without one)."""
    straight = track.extra.get("straight")
    if straight is None:
        return np.full(2, np.nan)
    return _speeds(track) * np.sin(wrap(_headings(track) - straight))


def _speeds(track: PoseTrack) -> np.ndarray:
    """(2,) the Ego's and the CAV's radar speed over ground, m/s."""
    return np.array([np.hypot(*track.v_own), np.hypot(*track.v_other)])


def _headings(track: PoseTrack) -> np.ndarray:
    """(2,) direction (rad) of the Ego's and the CAV's radar velocity in its own frame (NaN when
    slower than 0.5 m/s: no direction)."""
    out = np.full(2, np.nan)
    for k, v in enumerate((track.v_own, track.v_other)):
        if np.hypot(*v) >= 0.5:
            out[k] = np.arctan2(v[1], v[0])
    return out
