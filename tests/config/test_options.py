# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""One configuration: each option's default, range and message in one place (issue 24)."""

import dataclasses
import inspect

import numpy as np
import pytest

from astroalign_nd import config, find_match, find_sources, find_transform, register
from astroalign_nd.batch import register_batch
from astroalign_nd.cli.options import _FIELDS, _registration_options
from astroalign_nd.config import (DetectionConfig, MatchingConfig, ModelConfig,
                                  RegistrationConfig, ResampleConfig)
from astroalign_nd.matching import match_points
from astroalign_nd.options import cli_fields


def _defaults(func):
    return {n: p.default for n, p in inspect.signature(func).parameters.items()
            if p.default is not p.empty}


def _field_defaults(cls):
    return {f.name: f.default for f in dataclasses.fields(cls)
            if f.default is not dataclasses.MISSING}


def _same(a, b):
    return a == b or (isinstance(a, float) and np.isnan(a) and np.isnan(b))


@pytest.mark.parametrize("func, configs", [
    (find_transform, (ModelConfig, RegistrationConfig)),
    (find_match, (ModelConfig, RegistrationConfig)),
    (register, (ModelConfig, RegistrationConfig, ResampleConfig)),
    (register_batch, (ResampleConfig,)),
])
def test_signature_defaults_are_the_configs(func, configs):
    """Literal defaults in the signatures, for readable docs, are the configs' ones."""
    signature = _defaults(func)
    checked = 0
    for cls in configs:
        for name, default in _field_defaults(cls).items():
            if name in signature:
                assert _same(signature[name], default), (func.__name__, name)
                checked += 1
    assert checked >= 2


def test_detection_and_matching_defaults_are_the_configs():
    det = _defaults(find_sources)
    for name, default in _field_defaults(DetectionConfig).items():
        if name != "nsigma":  # None: registration's adaptive threshold; 5 alone
            assert det[name] == default, name
    assert det["nsigma"] == 5.0
    mat = _defaults(match_points)
    auto = {"tolerance": config.DEFAULT_TOLERANCE, "n_neighbors": config.DEFAULT_NEIGHBORS}
    for name, default in _field_defaults(MatchingConfig).items():
        assert mat[name] == auto.get(name, default), name
    assert _defaults(match_points)["transform_type"] == ModelConfig().transform_type


@pytest.mark.parametrize("call", [
    lambda: find_sources(np.zeros((32, 32)), fwhm=-1.0),
    lambda: find_transform(np.zeros((32, 32)), np.zeros((32, 32)), fwhm=-1.0),
    lambda: DetectionConfig(fwhm=-1.0),
])
def test_fwhm_has_one_rule_and_one_message(call):
    with pytest.raises(ValueError) as info:
        call()
    assert str(info.value) == ("fwhm must be a finite number > 0 and <= 10000 (pixels) or "
                               "None; got -1.0.")


def test_configs_are_frozen_and_checked():
    cfg = RegistrationConfig.from_keywords(tolerance=2, n_sources=40, max_sources=10)
    assert cfg.matching.tolerance == 2.0 and cfg.max_sources == 40  # raised to n_sources
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.matching.tolerance = 5.0
    with pytest.raises(TypeError, match="n_neighbors must be an integer"):
        MatchingConfig(n_neighbors=2.5)
    with pytest.raises(TypeError, match=r"unexpected keyword argument\(s\) \['min_area'\].*"
                       "Instead of astroalign's min_area"):
        RegistrationConfig.from_keywords(min_area=5)
    with pytest.raises(ValueError, match="degree"):
        ModelConfig("similarity", 3)


def test_the_search_leaves_the_config_unchanged(monkeypatch):
    """_escalate widens the tolerance on a copy of the config, never in place."""
    from astroalign_nd import registration
    from astroalign_nd.simulate import simulate_pair

    pair = simulate_pair((256, 256), n_stars=100, rotation=30.0, seed=1)
    cfg = RegistrationConfig()
    seen = []
    real = registration._attempt

    def spy(src, dst, sizes, src_stars, dst_stars, matching, *args, **kwargs):
        seen.append(matching.tolerance)
        return real(src, dst, sizes, src_stars, dst_stars, matching, *args, **kwargs)

    monkeypatch.setattr(registration, "_attempt", spy)
    registration.find_match_from_config(pair.source, pair.target, cfg)
    assert seen and all(t is not None and t >= config.DEFAULT_TOLERANCE for t in seen)
    assert cfg == RegistrationConfig()


def test_cli_options_come_from_the_configs():
    parser = _registration_options()
    actions = {a.dest: a for a in parser._actions}
    for cls in (ModelConfig, ResampleConfig, RegistrationConfig, DetectionConfig,
                MatchingConfig):
        for name, flag, kwargs in cli_fields(cls):
            assert name in _FIELDS and flag in actions[name].option_strings
            assert actions[name].help == kwargs["help"]
    # The defaults that the help text shows are the configs' ones.
    assert "(default: 200)" in actions["max_sources"].help
    assert "(default: 1e-6)" in actions["max_false_alarm"].help
    assert actions["n_sources"].default == RegistrationConfig().n_sources
    assert actions["order"].default == ResampleConfig().order


def test_apply_transform_lists_the_resample_config_keywords():
    from astroalign_nd import apply_transform
    from astroalign_nd.transforms import SimilarityTransform

    with pytest.raises(TypeError) as info:
        apply_transform(SimilarityTransform(), np.zeros((8, 8)), (8, 8), propagate_mask=True)
    for f in dataclasses.fields(ResampleConfig):
        assert f.name in str(info.value)
    assert "Instead of astroalign's propagate_mask" in str(info.value)
