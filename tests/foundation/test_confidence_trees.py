"""The confidence model's boosted trees: stored as arrays, evaluated with numpy as scikit-learn does."""

from __future__ import annotations

import numpy as np
from sklearn.ensemble import HistGradientBoostingClassifier

from mmatch.ego.confidence import load_model
from mmatch.ego.confidence_trees import TREE_SETTINGS, TreeEnsemble, fit_trees


def test_numpy_trees_agree_with_scikit_learn_and_survive_the_file():
    rng = np.random.default_rng(4)
    Z = rng.normal(size=(2000, 6))
    y = Z[:, 0] * Z[:, 1] + 0.3 * Z[:, 2] + rng.normal(0, 0.5, 2000) > 0      # an interaction
    trees = fit_trees(Z, y, seed=1)
    ref = HistGradientBoostingClassifier(random_state=1, **TREE_SETTINGS).fit(Z, y)
    test = rng.normal(size=(300, 6))
    np.testing.assert_allclose(trees.probability(test), ref.predict_proba(test)[:, 1], atol=1e-12)
    again = TreeEnsemble.from_dict(trees.to_dict(), 6)
    np.testing.assert_array_equal(again.probability(test), trees.probability(test))
    # it learns what a logistic regression cannot: the sign of a product
    p = trees.probability(np.array([[2.0, 2.0, 0, 0, 0, 0], [2.0, -2.0, 0, 0, 0, 0]]))
    assert p[0] > 0.8 and p[1] < 0.2
    assert len(trees.feature) == TREE_SETTINGS["max_iter"] and trees.probability(np.zeros((0, 6))).shape == (0,)


def test_the_packaged_model_averages_its_regression_and_trees():
    model = load_model()
    assert model.trees is not None and model.without_heading.trees is None
    x = model.mean + model.scale * np.random.default_rng(0).normal(size=(20, len(model.mean)))
    p, c = model.probability(x), model.confidence(x)
    assert np.all((c >= 0) & (c <= 1)) and not np.allclose(p, c)
    np.testing.assert_allclose(c, 0.5 * (p + model.trees.probability((x - model.mean) / model.scale)))
