"""Fit the confidence model of ego/confidence.py on evaluated scenes (`mmatch fit-confidence`).

Input: per-scene results of `mmatch.evaluate` run with confidence threshold 0 (every
candidate estimate emitted, each with its evidence and its true error). Output: a
`ProbabilityModel`: a logistic regression of "within 2 m / 5 deg" on the standardised
evidence (scikit-learn, L2), the covariance inflation that makes the 95 % ellipse hold
the truth for 95 % of the successful estimates, and the threshold: the lowest probability
at which the gross rate among the emitted stays at or below `max_gross` (keeping at least
`min_coverage` of the scenes when it can).

Beside the regression, `fit_tree_stage` fits boosted trees (ego/confidence_trees.py) on the
default matcher's candidates, whose mean with the regression is the confidence, and the chooser
that picks among a frame pair's candidates.

`fit_calibration` fits the map from the model's probability to the published confidence on
the estimates it chose (ProbabilityModel.calibration).

`gated_threshold` chooses the threshold instead on tuning families (e.g. wide physics and a
harsher one): the lowest at which the gross rate among what a single frame emits, with the
Fuser's other gates (`confidence.refusal`), stays within a bound in every family.

Choose the seeds you fit on apart from those you report on.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mmatch.ego.confidence import CHI2_3_95, FEATURES, ConfidenceConfig, ProbabilityModel, refusal
from mmatch.ego.confidence_trees import CHOOSER_SETTINGS, TREE_SETTINGS, choice_features, fit_trees


def training_rows(results: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every candidate transform of every scene: X (n, F), success (n,), gross (n,), scene index (n,)."""
    X, y, g, sid = [], [], [], []
    for k, r in enumerate(results):
        for c in r.get("alternatives") or []:
            X.append([c["evidence"][f] for f in FEATURES])
            y.append(c["success"])
            g.append(c["gross"])
            sid.append(k)
    return (np.array(X, float).reshape(-1, len(FEATURES)), np.array(y, bool), np.array(g, bool),
            np.array(sid, int))


def _mahalanobis_sq(c: dict) -> float:
    e = np.asarray(c["error"], float)
    try:
        return float(e @ np.linalg.solve(np.asarray(c["covariance"], float), e))
    except np.linalg.LinAlgError:
        return float("inf")


def fit_inflation(chosen: list[dict], target: float = 0.95) -> float:
    """Factor on the covariances so that the 95 % ellipse holds the truth for `target` of the
    chosen candidates that succeed (each with its error and its covariance at inflation 1)."""
    d2 = [_mahalanobis_sq(c) for c in chosen if c["success"]]
    d2 = [x for x in d2 if np.isfinite(x)]
    if not d2:
        return 1.0
    return float(max(np.quantile(d2, target) / CHI2_3_95, 1e-3))


def fit_calibration(p: np.ndarray, success: np.ndarray, iterations: int = 50) -> tuple[float, float]:
    """Platt's map (a, b) of `ProbabilityModel.calibration`: the logistic regression of success
    (n,) on the log-odds of the raw probabilities p (n,) of the estimates the model chose, by
    Newton's method (maximum likelihood with a prior worth one estimate pulling towards the
    identity a = 1, b = 0, which keeps a few estimates from a runaway fit; a kept > 0 so that
    the map stays monotone)."""
    p = np.asarray(p, float)
    y = np.asarray(success, float)
    ok = np.isfinite(p)
    p, y = np.clip(p[ok], 1e-6, 1 - 1e-6), y[ok]
    if len(p) < 10 or y.min() == y.max():
        raise ValueError(f"calibration needs at least 10 chosen estimates of both outcomes, got {len(p)} "
                         f"({int(y.sum())} right)")
    X = np.column_stack([np.log(p) - np.log1p(-p), np.ones(len(p))])
    w0 = np.array([1.0, 0.0])

    def loss(w: np.ndarray) -> float:                    # negative log-likelihood plus the prior
        z = X @ w
        return float(np.sum(np.logaddexp(0.0, z) - y * z) + 0.5 * np.sum((w - w0) ** 2))

    w = w0.copy()
    for _ in range(iterations):
        q = 1.0 / (1.0 + np.exp(-np.clip(X @ w, -40, 40)))
        H = X.T @ (X * (q * (1 - q))[:, None]) + np.eye(2)
        step = np.linalg.solve(H, X.T @ (y - q) - (w - w0))
        before, t = loss(w), 1.0
        while loss(w + t * step) > before and t > 1e-6:  # damped: Newton alone can overshoot
            t /= 2
        w = w + t * step
        if np.abs(t * step).max() < 1e-10:
            break
    return float(max(w[0], 1e-3)), float(w[1])


def choose_threshold(p: np.ndarray, gross: np.ndarray, n_scenes: int, max_gross: float,
                     min_coverage: float) -> float:
    """Lowest probability threshold whose emitted set has a gross rate <= max_gross; if that
    covers less than min_coverage of the scenes, the threshold that keeps min_coverage
    provided its gross rate stays within twice max_gross."""
    order = np.argsort(-p, kind="stable")
    cum_gross = np.cumsum(gross[order]) / np.arange(1, len(p) + 1)
    ok = np.flatnonzero(cum_gross <= max_gross)
    if len(ok) == 0:
        return 1.0
    k = int(ok.max())                                    # keep order[: k + 1]
    need = int(np.ceil(min_coverage * n_scenes)) - 1
    if k < need <= len(p) - 1 and cum_gross[need] <= 2 * max_gross:
        k = need
    return float(p[order[k]] - 1e-9)


def gated_threshold(families: list[list[dict]], max_gross: float, cfg: ConfidenceConfig = ConfidenceConfig(),
                    step: float = 0.01) -> tuple[float, list[dict]]:
    """The lowest threshold (a multiple of `step`) at which the gross rate among the estimates a
    single frame emits (the threshold with the Fuser's other gates, `refusal`) stays <=
    max_gross in every family:
    each family the per-scene results of `mmatch.evaluate` at threshold 0 (a scene's chosen
    candidate with its confidence, evidence and whether it is gross). Returns the threshold and,
    per family, its emitted share, success and gross rate there (a threshold above every gross
    estimate holds by emitting nothing; 1.0 when none below 1 does)."""
    rows = [[(float(np.nan_to_num(r["confidence"], nan=-1.0)), r.get("evidence") or {},
              bool(r["candidate"]["gross"]), bool(r["candidate"]["success"]), r.get("predicted"))
             for r in fam if r.get("candidate") and r.get("confidence") is not None] for fam in families]
    sizes = [max(len(fam), 1) for fam in families]

    def outcome(thr: float) -> list[dict]:
        out = []
        for fam, n in zip(rows, sizes):
            kept = [(g, ok) for c, ev, g, ok, pub in fam if refusal(c, ev, thr, cfg, pub) is None]
            gross = sum(g for g, _ in kept)
            out.append(dict(emitted=len(kept) / n, success=sum(ok for _, ok in kept) / n,
                            gross=gross / len(kept) if kept else 0.0))
        return out

    for thr in np.round(np.arange(1, int(round(1 / step))) * step, 6):
        res = outcome(float(thr))
        if all(f["gross"] <= max_gross for f in res):
            return float(thr), res
    return 1.0, outcome(1.0)


def neutral_model() -> ProbabilityModel:
    """A model of today's features that rates every candidate 0.5 with no inflation: what an
    evaluation for fitting runs under when the packaged model's features are stale."""
    n = len(FEATURES)
    return ProbabilityModel(FEATURES, np.zeros(n), np.ones(n), np.zeros(n), 0.0, 1.0, 0.0)


def fit_model(results: list[dict], max_gross: float = 0.015, min_coverage: float = 0.8,
              C: float = 1.0, meta: dict | None = None, inflation_used: float = 1.0) -> ProbabilityModel:
    """The probability model, inflation and threshold from evaluated scenes (see module doc).

    The regression learns from every candidate of every scene (right and wrong ones side by
    side); the threshold and the inflation from the candidate the model would choose in each
    scene, as the Fuser does. inflation_used: the covariance inflation the results were
    evaluated with (their covariances carry it; the fitted factor is relative to it).
    """
    from sklearn.linear_model import LogisticRegression

    X, y, g, sid = training_rows(results)
    if len(X) < 20 or y.all() or not y.any():
        raise ValueError(f"need at least 20 candidates with both outcomes, got {len(X)}")
    mean, scale = X.mean(axis=0), X.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    clf = LogisticRegression(C=C, max_iter=5000)
    clf.fit((X - mean) / scale, y)
    model = ProbabilityModel(FEATURES, mean, scale, clf.coef_[0].astype(float), float(clf.intercept_[0]))
    p = model.probability(X)
    chosen_rows, chosen = [], []
    for k in np.unique(sid):
        idx = np.flatnonzero(sid == k)
        best = idx[int(np.argmax(p[idx]))]
        chosen_rows.append(best)
        chosen.append(results[k]["alternatives"][int(best - idx[0])])
    chosen_rows = np.asarray(chosen_rows)
    n_scenes = sum(1 for r in results if "rejected" not in r)
    thr = choose_threshold(p[chosen_rows], g[chosen_rows], n_scenes, max_gross, min_coverage)
    info = dict(meta or {}, candidates=len(X), scenes=n_scenes, chosen=len(chosen_rows),
                chosen_success=float(y[chosen_rows].mean()), chosen_gross=float(g[chosen_rows].mean()),
                candidate_success=float(y.mean()), max_gross=max_gross, min_coverage=min_coverage)
    return ProbabilityModel(FEATURES, mean, scale, model.coef, model.intercept,
                            fit_inflation(chosen) * inflation_used, thr, info)


def fit_tree_stage(results: list[dict], model: ProbabilityModel, meta: dict | None = None) -> ProbabilityModel:
    """`model` with boosted trees (ego/confidence_trees.py) fit beside its regression on every
    candidate of the evaluated scenes, over the regression's standardised evidence, and the
    chooser over each scene's candidates relative to each other."""
    X, y, _, sid = training_rows(results)
    if len(X) < 20 or y.all() or not y.any():
        raise ValueError(f"need at least 20 candidates with both outcomes, got {len(X)}")
    Z = model.standardise(X)
    trees = fit_trees(Z, y)
    p = model.probability(X)
    C = np.zeros((len(X), 2 * Z.shape[1] + 4))
    for k in np.unique(sid):
        idx = np.flatnonzero(sid == k)
        C[idx] = choice_features(Z[idx], p[idx])
    chooser = fit_trees(C, y, settings=CHOOSER_SETTINGS)
    info = dict(meta or {}, candidates=len(X), candidate_success=float(y.mean()), settings=TREE_SETTINGS,
                chooser_settings=CHOOSER_SETTINGS)
    return replace(model, trees=trees, chooser=chooser, meta=dict(model.meta, trees=info))
