# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The parameter layers of the transform types: one per type, agreeing with its
model, and a new type that brings its own layer fitted, matched and solved
jointly by `~astroalign_nd.solve_sequence` without any other change.
"""

import numpy as np
import pytest

from astroalign_nd import solve_sequence
from astroalign_nd.sequence import adjust
from astroalign_nd.simulate import simulate_views
from astroalign_nd.transforms import (TRANSFORM_REGISTRY, SimilarityTransform, fit_transform,
                                      register_transform_type, transform_class,
                                      unregister_transform_type)

from _toy_transforms import ScaleShift

RNG = np.random.default_rng(7)
POINTS = RNG.uniform(-1.0, 1.0, (40, 2))

#: One model of each built-in type, by registry name (parity -1 where there is one).
MODELS = {
    "translation": dict(translation_x=3.0, translation_y=-2.0),
    "euclidean": dict(rotation=20.0, translation_x=1.0, translation_y=0.5, parity=-1),
    "similarity": dict(scale=1.2, rotation=-35.0, translation_x=0.2, translation_y=4.0,
                       parity=-1),
    "affine": dict(a11=1.1, a12=0.2, a21=-0.1, a22=0.9, translation_x=2.0, translation_y=1.0),
    "projective": dict(h11=1.01, h12=0.02, h13=0.3, h21=-0.01, h22=0.98, h23=-0.2, h31=0.03,
                       h32=-0.02),
}


def _model_and_layer(name):
    values = MODELS[name]
    cls = TRANSFORM_REGISTRY[name].cls
    model = cls(**values)
    return model, cls.layer(parity=values.get("parity", 1))


@pytest.mark.parametrize("name", sorted(MODELS))
def test_each_layer_predicts_as_its_model_and_differentiates_it(name):
    model, layer = _model_and_layer(name)
    if name == "projective":
        m = model.matrix
        theta = np.array([*m[0], *m[1], m[2, 0], m[2, 1]])
    else:
        theta = layer.from_matrix(model.matrix)
        assert np.allclose(layer.to_matrix(theta), model.matrix, rtol=0, atol=1e-13)
    assert len(theta) == layer.k
    pred = layer.predict(theta, POINTS)
    assert np.allclose(pred, np.column_stack(model(*POINTS.T)), rtol=0, atol=1e-12)
    # The design is the Jacobian of the prediction (central differences).
    design = layer.design(POINTS, theta)
    for j in range(layer.k):
        step = np.zeros(layer.k)
        step[j] = 1e-6
        num = (layer.predict(theta + step, POINTS) - layer.predict(theta - step, POINTS)) / 2e-6
        assert np.allclose(design[:, :, j], num, rtol=0, atol=1e-7), j


@pytest.mark.parametrize("name, parity", [("translation", 1), ("euclidean", 1),
                                          ("euclidean", -1), ("similarity", 1),
                                          ("similarity", -1), ("affine", 1)])
def test_stacked_matrices_are_each_rows_matrix(name, parity):
    # The jackknife turns its stacked fits into matrices at once: the same bits
    # as one row at a time (a sign of zero included), and the model's matrix.
    cls = TRANSFORM_REGISTRY[name].cls
    layer = cls.layer(parity=parity)
    theta = np.random.default_rng(3).normal(size=(7, layer.k))
    theta[0, :] = 0.0  # zeros (and their negatives) keep their sign
    mats = layer.to_matrices(theta)
    single = np.array([layer.to_matrix(t) for t in theta])
    assert mats.shape == (7, 3, 3)
    assert np.array_equal(mats.view(np.int64), single.view(np.int64))
    model, _ = _model_and_layer(name)
    model_layer = cls.layer(parity=MODELS[name].get("parity", 1))
    stacked = model_layer.to_matrices(model_layer.from_matrix(model.matrix)[None])
    assert np.allclose(stacked[0], model.matrix, rtol=0, atol=1e-13)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_polynomial_layer_is_linear_in_its_coefficients(degree):
    layer = transform_class("polynomial").layer(degree=degree)
    theta = RNG.normal(size=layer.k)
    design = layer.design(POINTS)
    assert layer.linear and design.shape == (len(POINTS), 2, layer.k)
    assert np.allclose(layer.predict(theta, POINTS), np.einsum("nik,k->ni", design, theta))
    assert layer.affine_in_position == (degree == 1)


def test_the_joint_solve_asks_the_layer_only():
    for name in ("translation", "euclidean", "similarity", "affine"):
        layer = adjust.layer_of(name)
        model, _ = _model_and_layer(name)
        m = model.matrix
        centre, parity = np.array([10.0, -4.0]), -1.0 if model.mirrored else 1.0
        theta = adjust.theta_from_matrix(layer, m, centre, parity)
        assert np.allclose(adjust.matrix_from_theta(layer, theta, centre, parity), m, rtol=0,
                           atol=1e-12), name


# -- a new type (tests/_toy_transforms.py): its model class, its layer, its registry entry;
# nothing else --------------------------------------------------------------------------------

@pytest.fixture
def scaleshift():
    yield register_transform_type("scaleshift", ScaleShift, linear=True)
    unregister_transform_type("scaleshift")


def test_a_new_type_is_fitted_through_its_layer(scaleshift):
    truth = ScaleShift(scale=1.02, translation_x=4.0, translation_y=-3.0)
    src = RNG.uniform(0, 500, (30, 2))
    model, cov, _ = fit_transform(src, np.column_stack(truth(*src.T)), "scaleshift")
    assert type(model) is ScaleShift and cov.shape == (3, 3)
    assert np.allclose(model.matrix, truth.matrix, rtol=0, atol=1e-9)


def test_a_new_type_is_solved_jointly(scaleshift):
    # Three frames of one field, each scaled (no rotation) and shifted.
    frames_to_sky = [SimilarityTransform(scale=s, rotation=0.0, translation_x=tx,
                                         translation_y=ty)
                     for s, tx, ty in ((1.0, 0.0, 0.0), (1.01, 40.0, 25.0),
                                       (0.99, -30.0, 45.0))]
    seq = simulate_views(frames_to_sky, (200, 200), n_stars=150, seed=5)
    sol = solve_sequence(seq.frames, reference=0, transform_type="scaleshift")
    assert sol.unsolved == {}
    for f in (1, 2):
        got = sol.transforms[f]
        assert type(got) is ScaleShift
        truth = seq.truth(f, 0)
        corners = np.array([[0.0, 0.0], [199.0, 0.0], [0.0, 199.0], [199.0, 199.0]])
        err = np.column_stack(got(*corners.T)) - np.column_stack(truth(*corners.T))
        assert np.max(np.hypot(*err.T)) < 0.1  # px, at the frame's corners
