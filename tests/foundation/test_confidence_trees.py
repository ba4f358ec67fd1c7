"""The confidence model's boosted trees: stored as arrays, evaluated with numpy as scikit-learn does."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from sklearn.ensemble import HistGradientBoostingClassifier

from mmatch.ego.confidence import load_model
from mmatch.ego.confidence_trees import TREE_SETTINGS, TreeEnsemble, choice_features, fit_trees


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
    assert model.trees is not None and model.without_heading.trees is not None
    x = model.mean + model.scale * np.random.default_rng(0).normal(size=(20, len(model.mean)))
    p, c = model.probability(x), model.rate(x)[0]
    assert np.all((c >= 0) & (c <= 1)) and not np.allclose(p, c)
    np.testing.assert_allclose(c, 0.5 * (p + model.trees.probability((x - model.mean) / model.scale)))


def test_the_chooser_reads_each_candidate_against_its_competitors():
    Z = np.array([[0.0, 1.0], [2.0, -1.0], [1.0, 0.0]])
    C = choice_features(Z, np.array([0.2, 0.7, 0.5]))
    np.testing.assert_allclose(C[:, :2], Z)
    np.testing.assert_allclose(C[:, 2:4], Z - [2.0, 1.0])              # relative to the best of each
    np.testing.assert_allclose(C[:, 4], [2, 0, 1])                      # rank of the regression's probability
    np.testing.assert_allclose(C[:, 5], [-0.5, 0.0, -0.2])
    assert (C[:, 6] == 3).all() and np.allclose(C[:, 7], [0.2, 0.7, 0.5])
    assert choice_features(np.zeros((0, 2)), np.zeros(0)).shape == (0, 8)
    model = load_model()
    assert model.chooser is not None and model.without_heading.chooser is not None
    x = model.mean + model.scale * np.random.default_rng(1).normal(size=(5, len(model.mean)))
    c = model.rate(x)[1]
    assert c.shape == (5,) and np.all((c >= 0) & (c <= 1)) and not np.allclose(c, model.probability(x))
    plain = replace(model, chooser=None)                      # without a chooser the regression chooses
    assert plain.rate(x)[1].tolist() == plain.probability(x).tolist()
