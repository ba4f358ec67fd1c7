"""Boosted trees beside the confidence model's logistic regression (ego/confidence.py).

The logistic regression weighs each piece of evidence alone; some only mean something together
(a strong RM-net score with a background that fits nowhere else, a lone pair seen by both
radars). A small gradient-boosted tree ensemble over the same standardised evidence learns
those interactions. Its probability and the regression's are averaged into the confidence
that ranks and gates an estimate. The average does not choose among one frame pair's
candidates: choosing by it, 1.5 points fewer scenes had their right candidate chosen on the
seeds the ensemble was chosen on.

A second ensemble, the chooser, picks among one frame pair's candidates: it reads each
candidate's evidence, the same evidence relative to the best of its frame pair's candidates, and
the regression's probability with its rank and gap to the best (`choice_features`), so it learns
what tells a right candidate from its competitors rather than from every other scene's.

Fit with scikit-learn (`fit_trees`, `mmatch fit-confidence`), stored as plain arrays in the
model file and evaluated here with numpy: every tree of the ensemble descends one level per step,
all candidates at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from mmatch.errors import ConfigError

# chosen on the default matcher's candidates of wide hard seeds 1, 3, 4 (as the arbiter uses the
# confidence, ranked by it: gross at coverage 0.8 0.031 -> 0.027) among depths 2-4 and 150-600
# rounds; trees of depth 3 hold at most 8 leaves
TREE_SETTINGS = {"max_depth": 3, "learning_rate": 0.05, "max_iter": 150, "l2_regularization": 1.0}
# the chooser's, chosen on the same seeds among depths 2-3 and 150-300 rounds (right candidate
# chosen: 0.778 with the regression, 0.780 / 0.785 with depth 3 and 150 / 300 rounds)
CHOOSER_SETTINGS = {"max_depth": 3, "learning_rate": 0.05, "max_iter": 300, "l2_regularization": 1.0}


def choice_features(Z: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(n, 2 F + 4) what the chooser reads of one frame pair's n candidates: their standardised
    evidence Z (n, F); the same minus its maximum over the candidates; the regression's
    probability p (n,), its rank among them (0: the highest), its gap to the highest; n."""
    Z = np.atleast_2d(np.asarray(Z, float))
    p = np.asarray(p, float).reshape(-1)
    n = len(Z)
    if n == 0:
        return np.zeros((0, 2 * Z.shape[1] + 4))
    F = Z.shape[1]
    out = np.empty((n, 2 * F + 4))
    out[:, :F] = Z
    out[:, F:2 * F] = Z - Z.max(axis=0)
    out[np.argsort(-p, kind="stable"), 2 * F] = np.arange(n)
    out[:, 2 * F + 1] = p - p.max()
    out[:, 2 * F + 2] = n
    out[:, 2 * F + 3] = p
    return out


@dataclass(frozen=True)
class TreeEnsemble:
    """Binary trees over standardised features; raw score = baseline + sum of the leaves reached.

    feature, threshold, left, right, value: (T, M) per tree and node (M: the most nodes of any
    tree; a leaf has left = right = -1 and its value; padding nodes are never reached); a
    sample goes left where its feature <= threshold.
    """

    feature: np.ndarray
    threshold: np.ndarray
    left: np.ndarray
    right: np.ndarray
    value: np.ndarray
    baseline: float
    depth: int

    def probability(self, Z: np.ndarray) -> np.ndarray:
        """(n,) probabilities of standardised features Z (n, F)."""
        Z = np.atleast_2d(np.asarray(Z, float))
        n, F = Z.shape
        feature, threshold, left, right, node = self._flat           # node: (T, 1) the roots, then (T, n)
        row = np.arange(n) * F
        for _ in range(self.depth):
            go_left = Z.ravel()[row + feature[node]] <= threshold[node]
            node = np.where(go_left, left[node], right[node])
        raw = self.baseline + self.value.ravel()[node].sum(axis=0)
        return 1.0 / (1.0 + np.exp(-np.clip(raw, -40, 40)))

    @cached_property
    def _flat(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The trees' nodes in one flat array (node m of tree k at k M + m): feature (0 at a leaf),
        threshold, left and right child (a leaf its own, so every sample takes `depth` steps), and
        (T, 1) each tree's root."""
        T, M = self.feature.shape
        first = np.arange(T)[:, None] * M
        leaf = self.left < 0
        own = np.arange(M)[None]
        left = np.where(leaf, own, self.left) + first
        right = np.where(leaf, own, self.right) + first
        return np.maximum(self.feature, 0).ravel(), self.threshold.ravel(), left.ravel(), right.ravel(), first

    def to_dict(self) -> dict:
        return {"feature": self.feature.tolist(), "threshold": self.threshold.tolist(),
                "left": self.left.tolist(), "right": self.right.tolist(), "value": self.value.tolist(),
                "baseline": float(self.baseline), "depth": int(self.depth)}

    @classmethod
    def from_dict(cls, d: dict, n_features: int, where: str = "<model>") -> "TreeEnsemble":
        """Parse and check a stored ensemble (ConfigError naming `where` when it is malformed)."""
        try:
            ints = [np.asarray(d[k], np.int64) for k in ("feature", "left", "right")]
            thr, val = np.asarray(d["threshold"], float), np.asarray(d["value"], float)
            out = cls(ints[0], thr, ints[1], ints[2], val, float(d["baseline"]), int(d["depth"]))
        except (ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"{where}: trees: not a tree ensemble ({exc})") from exc
        shape = out.feature.shape
        M = shape[1] if len(shape) == 2 else 0
        ok = len(shape) == 2 and M > 0 and all(a.shape == shape for a in (thr, val, out.left, out.right)) \
            and 1 <= out.depth <= 16 and np.all(np.isfinite(thr)) and np.all(np.isfinite(val)) \
            and np.isfinite(out.baseline) and np.all(out.feature < n_features) \
            and np.all((out.left == -1) | ((out.left > 0) & (out.left < M))) \
            and np.all((out.right == -1) | ((out.right > 0) & (out.right < M))) \
            and np.all((out.left < 0) == (out.right < 0)) and np.all((out.left < 0) | (out.feature >= 0))
        if not ok:
            raise ConfigError(f"{where}: trees: expected (trees, nodes) arrays over {n_features} features, "
                              f"child indices within each tree, depth 1-16")
        return out


def fit_trees(Z: np.ndarray, y: np.ndarray, seed: int = 0, settings: dict | None = None) -> TreeEnsemble:
    """Fit an ensemble (settings, default TREE_SETTINGS) on features Z (n, F) and outcomes y (n,)."""
    from sklearn.ensemble import HistGradientBoostingClassifier

    settings = settings or TREE_SETTINGS
    clf = HistGradientBoostingClassifier(random_state=seed, **settings).fit(Z, y)
    trees = [p[0].nodes for p in clf._predictors]   # one predictor per round (binary)
    M = max(len(t) for t in trees)
    T = len(trees)
    feature = np.full((T, M), -1, np.int64)
    threshold = np.zeros((T, M))
    left = np.full((T, M), -1, np.int64)
    right = np.full((T, M), -1, np.int64)
    value = np.zeros((T, M))
    for k, nodes in enumerate(trees):
        n = len(nodes)
        leaf = nodes["is_leaf"].astype(bool)
        feature[k, :n] = np.where(leaf, -1, nodes["feature_idx"].astype(np.int64))
        threshold[k, :n] = nodes["num_threshold"]
        left[k, :n] = np.where(leaf, -1, nodes["left"].astype(np.int64))
        right[k, :n] = np.where(leaf, -1, nodes["right"].astype(np.int64))
        value[k, :n] = np.where(leaf, nodes["value"], 0.0)
    baseline = float(np.ravel(clf._baseline_prediction)[0])
    return TreeEnsemble(feature, threshold, left, right, value, baseline, int(settings["max_depth"]))
