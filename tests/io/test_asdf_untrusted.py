# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The ASDF converters given untrusted values: a valid model or a ValueError (hypothesis)."""

import asdf
import numpy as np
import pytest
from asdf.testing.helpers import yaml_to_asdf
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from astroalign_nd.io.asdf import extension
from astroalign_nd.transforms import (AffineTransform, EuclideanTransform, SimilarityTransform,
                                      TranslationTransform)

FAST = settings(max_examples=12, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])


# -- ASDF converters -----------------------------------------------------------------

URI = "asdf://astroalign-nd.org/astroalign_nd/tags"


@pytest.fixture(scope="module")
def asdf_config():
    with asdf.config_context() as config:
        if not any(e.extension_uri.startswith("asdf://astroalign-nd.org")
                   for e in config.extensions):
            for mapping in extension.get_resource_mappings():
                config.add_resource_mapping(mapping)
            for ext in extension.get_extensions():
                config.add_extension(ext)
        config.validate_on_read = False  # asdf's default: the converters must check
        config.warn_on_failed_conversion = False
        yield config


def _read(name, params):
    body = "\n".join(f"  {k}: {v}" for k, v in params.items())
    with asdf.open(yaml_to_asdf(f"model: !<{URI}/{name}_transform-1.0.0>\n{body}\n")) as af:
        return af["model"]


SIM = {"scale": 1.0, "rotation": 0.1, "translation_x": 1.0, "translation_y": 2.0,
       "parity": 1}


@pytest.mark.parametrize("bad, match", [
    ({"parity": 0}, "parity"), ({"parity": 5}, "parity"), ({"scale": "[1, 2]"}, "scale"),
    ({"scale": 0}, "scale"), ({"scale": -1}, "scale"), ({"rotation": ".nan"}, "rotation"),
    ({"translation_x": ".inf"}, "translation_x"), ({"translation_y": "'ten'"}, "translation_y"),
])
def test_asdf_untrusted_values_refused(asdf_config, bad, match):
    with pytest.raises(ValueError, match=match):
        _read("similarity", {**SIM, **bad})


def test_asdf_singular_affine_refused(asdf_config):
    with pytest.raises(ValueError, match="singular"):
        _read("affine", {"a11": 1, "a12": 2, "a21": 2, "a22": 4, "translation_x": 0,
                         "translation_y": 0})


def test_asdf_default_config_gives_no_bad_model(asdf_config):
    """With asdf's own defaults the bad node stays raw data, with our message."""
    with asdf.config_context() as config:
        config.validate_on_read = False
        config.warn_on_failed_conversion = True
        with pytest.warns(Warning, match="parity must be"):
            model = _read("similarity", {**SIM, "parity": 5})
    assert not isinstance(model, SimilarityTransform)


@FAST
@given(name=st.sampled_from(["translation", "euclidean", "similarity", "affine"]),
       values=st.lists(st.one_of(st.floats(), st.integers(-3, 3)), min_size=6, max_size=6))
def test_asdf_any_values_give_valid_model_or_error(asdf_config, name, values):
    cls = {"translation": TranslationTransform, "euclidean": EuclideanTransform,
           "similarity": SimilarityTransform, "affine": AffineTransform}[name]
    params = dict(zip(cls.param_names, values))
    text = {k: (".nan" if np.isnan(v) else ".inf" if v == np.inf else "-.inf"
                if v == -np.inf else repr(v)) for k, v in params.items()}
    try:
        model = _read(name, text)
    except ValueError as exc:
        assert "node" in str(exc)
        return
    m = model.matrix
    assert np.all(np.isfinite(m)) and abs(np.linalg.det(m[:2, :2])) > 0
    # The matrix and the evaluation agree.
    x, y = np.array([0.0, 10.0, -3.0]), np.array([0.0, 5.0, 7.0])
    got = np.column_stack(model(x, y))
    np.testing.assert_allclose(got, np.column_stack([x, y]) @ m[:2, :2].T + m[:2, 2],
                               rtol=1e-9, atol=1e-6 * max(1.0, np.abs(m).max()))
