# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Tests of the ASDF extension of astroalign_nd (astroalign_nd.io.asdf).

The extension is normally registered by the ``asdf.extensions`` and
``asdf.resource_mappings`` entry points.  When the package is not installed
(running from a source tree with ``PYTHONPATH``) the ``asdf_extension``
fixture registers it by hand for the duration of the module, so the round
trips still run; `test_fresh_process_uses_entry_points` is the one test that
needs the installed entry points.
"""

import importlib.metadata
import json
import os
import re
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import asdf
import numpy as np
import pytest
from astropy import units as u
import yaml
from asdf.exceptions import ValidationError
from asdf.extension import Converter
from asdf.testing.helpers import yaml_to_asdf
from astropy.modeling import models
from numpy.testing import assert_allclose

from astroalign_nd.io.asdf import extension
from astroalign_nd.transforms import (
    AffineTransform,
    EuclideanTransform,
    PolynomialTransform,
    ProjectiveTransform,
    SimilarityTransform,
    TranslationTransform,
)

from _helpers import SAMPLE_XS, SAMPLE_YS, sample_linear_transforms

URI_BASE = "asdf://astroalign-nd.org/astroalign_nd"
EXTENSION_URI = f"{URI_BASE}/extensions/astroalign_nd-1.1.0"
MANIFEST_URI = f"{URI_BASE}/manifests/astroalign_nd-1.1.0"
# The first manifest, without the non-linear models: files written with it must still read.
OLD_EXTENSION_URI = f"{URI_BASE}/extensions/astroalign_nd-1.0.0"
OLD_MANIFEST_URI = f"{URI_BASE}/manifests/astroalign_nd-1.0.0"
RESOURCES = Path(extension.__file__).parent / "resources"
DATA = Path(__file__).parents[1] / "data"
SCHEMA_NAMES = ["translation", "euclidean", "similarity", "affine", "projective", "polynomial"]
SCHEMA_URIS = [f"{URI_BASE}/schemas/{name}_transform-1.0.0" for name in SCHEMA_NAMES]
TAG_URIS = [f"{URI_BASE}/tags/{name}_transform-1.0.0" for name in SCHEMA_NAMES]
CLASSES = {"translation": TranslationTransform, "euclidean": EuclideanTransform,
           "similarity": SimilarityTransform, "affine": AffineTransform,
           "projective": ProjectiveTransform, "polynomial": PolynomialTransform}

XS, YS = SAMPLE_XS, SAMPLE_YS

TRANSFORMS = {
    **sample_linear_transforms(),
    "projective": ProjectiveTransform(h11=1.01, h12=0.02, h13=5.0 / 3.0, h21=-0.01, h22=0.99,
                                      h23=-3.5, h31=2.0e-6, h32=-1.0e-6 / 3.0),
    "polynomial": PolynomialTransform(degree=3, crpix=(2047.5, 1023.5), a11=1.001, a12=-0.02,
                                      a21=0.02, a22=1.001, translation_x=2050.0 / 3.0,
                                      translation_y=1020.25, A_2_0=3e-7, A_3_0=-1.8e-9,
                                      A_1_2=-1.8e-9, B_2_1=-1.8e-9, B_0_3=-1.8e-9 / 7.0,
                                      domain=(0.0, 4095.0, 0.0, 2047.0)),
    "polynomial-5": PolynomialTransform(degree=5, crpix=(0.0, 0.0), A_5_0=1e-17, B_4_1=2e-17,
                                        A_2_0=1e-6, domain=(-1000.0, 3000.0, -45.5, 3000.0)),
}


def _extension_registered():
    return any(ext.extension_uri == EXTENSION_URI for ext in asdf.get_config().extensions)


@pytest.fixture(scope="module", autouse=True)
def asdf_extension():
    """
    Make sure the extension is registered, falling back to registering it by
    hand when the entry points are not installed; validate files on read.
    """
    with asdf.config_context() as config:
        if not _extension_registered():
            for mapping in extension.get_resource_mappings():
                config.add_resource_mapping(mapping)
            for ext in extension.get_extensions():
                config.add_extension(ext)
        config.validate_on_read = True
        yield config


def _roundtrip(obj, tmp_path):
    path = tmp_path / "roundtrip.asdf"
    asdf.AsdfFile({"obj": obj}).write_to(path)
    with asdf.open(path, lazy_load=False, memmap=False) as af:
        return af["obj"]


def _assert_same_evaluation(model, other):
    expected = np.array(model(XS, YS))
    actual = np.array(other(XS, YS))
    assert_allclose(actual, expected, rtol=0.0, atol=1e-9)


# -- extension and resources --------------------------------------------------


def test_extension_registered():
    assert _extension_registered()
    [ext] = [e for e in asdf.get_config().extensions if e.extension_uri == EXTENSION_URI]
    tag_uris = {tag.tag_uri for tag in ext.tags}
    assert tag_uris == set(TAG_URIS)
    assert len(ext.converters) == 6
    # The first extension is still there, for files written with it.
    [old] = [e for e in asdf.get_config().extensions if e.extension_uri == OLD_EXTENSION_URI]
    assert {tag.tag_uri for tag in old.tags} == set(TAG_URIS[:4])


def test_converters_implement_interface():
    converters = extension.get_converters()
    assert len(converters) == 6
    types = set()
    for converter in converters:
        assert isinstance(converter, Converter)
        types.update(converter.types)
    assert types == {f"{cls.__module__}.{cls.__name__}" for cls in CLASSES.values()}
    # One shared implementation on asdf's public API, nothing from asdf-astropy's internals.
    assert {type(c) for c in converters} == {converters[0].__class__}
    assert type(converters[0]).__mro__[1] is Converter
    source = (Path(extension.__file__).parent / "converters.py").read_text()
    assert "asdf_astropy" not in source


def test_get_extensions_builds_new_objects():
    # Built on each call, inside the function (not at import).
    first, second = extension.get_extensions(), extension.get_extensions()
    assert len(first) == len(extension.ASTROALIGN_ND_MANIFEST_URIS)
    assert first[0] is not second[0]
    assert first[0].extension_uri == EXTENSION_URI


def test_resource_mappings_cover_all_files():
    uris = set()
    for mapping in extension.get_resource_mappings():
        uris.update(mapping)
    assert uris == {MANIFEST_URI, OLD_MANIFEST_URI, *SCHEMA_URIS}
    manager = asdf.get_config().resource_manager
    for uri in uris:
        assert yaml.safe_load(manager[uri])["id"] == uri


def test_manifest_matches_converters_and_tag_table():
    manifest = yaml.safe_load(asdf.get_config().resource_manager[MANIFEST_URI])
    assert manifest["extension_uri"] == EXTENSION_URI
    tags = {tag["tag_uri"]: tag["schema_uri"] for tag in manifest["tags"]}
    assert tags == dict(zip(TAG_URIS, SCHEMA_URIS))
    assert set(extension.ASTROALIGN_ND_TAG_URIS.values()) == set(TAG_URIS)
    patterns = [t for c in extension.get_converters() for t in c.tags]
    for tag in TAG_URIS:
        assert sum(asdf.util.uri_match(p, tag) for p in patterns) == 1, tag


# -- schemas ------------------------------------------------------------------


@pytest.mark.parametrize("name", SCHEMA_NAMES)
def test_schema_is_valid(name):  # noqa: C901
    path = RESOURCES / "schemas" / f"{name}_transform-1.0.0.yaml"
    schema = yaml.safe_load(path.read_text())
    asdf.schema.check_schema(schema)
    loaded = asdf.schema.load_schema(f"{URI_BASE}/schemas/{name}_transform-1.0.0",
                                     resolve_references=True)
    assert loaded["id"] == f"{URI_BASE}/schemas/{name}_transform-1.0.0"
    # It extends the transform base schema shipped by asdf-transform-schemas.
    base = schema["allOf"][0]["$ref"]
    assert base.startswith("http://stsci.edu/schemas/asdf/transform/transform-")
    asdf.schema.load_schema(base)
    # Every model parameter is a required number (the polynomial's coefficients,
    # whose names depend on the degree, match a pattern).
    body = schema["allOf"][1]
    if name == "polynomial":
        names = PolynomialTransform(degree=5).param_names
        assert set(body["required"]) == {"degree", *names[:8]}
        assert body["properties"]["degree"]["type"] == "integer"
        for param in names[8:]:
            [pattern] = body["patternProperties"]
            assert re.match(pattern, param)
            assert body["patternProperties"][pattern]["type"] == "number"
        names = names[:8]
    else:
        names = CLASSES[name].param_names
        assert set(body["required"]) == set(names)
    for param in names:
        assert body["properties"][param]["type"] == "number"


MANIFEST_SCHEMA_URI = "asdf://asdf-format.org/core/schemas/extension_manifest-1.0.0"


@pytest.mark.parametrize("version", ["1.0.0", "1.1.0"])
def test_manifest_is_valid(version):
    manifest = yaml.safe_load(
        (RESOURCES / "manifests" / f"astroalign_nd-{version}.yaml").read_text())
    assert manifest["id"] == f"{URI_BASE}/manifests/astroalign_nd-{version}"
    asdf.schema.validate(manifest, schema=asdf.schema.load_schema(MANIFEST_SCHEMA_URI))
    for tag in manifest["tags"]:
        assert {"tag_uri", "schema_uri", "title", "description"} <= set(tag)
    broken = {**manifest, "tags": [{"schema_uri": SCHEMA_URIS[0]}]}
    with pytest.raises(ValidationError):
        asdf.schema.validate(broken, schema=asdf.schema.load_schema(MANIFEST_SCHEMA_URI))


def _schema_examples(name):
    schema = yaml.safe_load((RESOURCES / "schemas" / f"{name}_transform-1.0.0.yaml").read_text())
    return [example[-1] for example in schema["examples"]]


@pytest.mark.parametrize("name", SCHEMA_NAMES)
def test_schema_examples_read(name):
    examples = _schema_examples(name)
    assert examples
    for text in examples:
        content = "model: " + textwrap.indent(text.strip(), "  ").lstrip()
        with asdf.open(yaml_to_asdf(content)) as af:
            model = af["model"]
        assert type(model).__name__.lower() == f"{name}transform"


def _tagged_yaml(name, params):
    body = "\n".join(f"  {key}: {value}" for key, value in params.items())
    return f"model: !<{URI_BASE}/tags/{name}_transform-1.0.0>\n{body}\n"


VALID_PARAMS = {
    "translation": {"translation_x": 1.0, "translation_y": 2.0},
    "euclidean": {"rotation": 0.5, "translation_x": 1.0, "translation_y": 2.0, "parity": -1.0},
    "similarity": {"scale": 2.0, "rotation": 0.5, "translation_x": 1.0, "translation_y": 2.0,
                   "parity": 1},
    "affine": {"a11": 1.0, "a12": 0.1, "a21": 0.2, "a22": 0.9, "translation_x": 1.0,
               "translation_y": 2.0},
    "projective": {"h11": 1.0, "h12": 0.1, "h13": 3.0, "h21": 0.2, "h22": 0.9, "h23": -4.0,
                   "h31": 0.001, "h32": -0.002},
    "polynomial": {"degree": 2, "crpix1": 10.0, "crpix2": 20.0, "a11": 1.0, "a12": 0.1,
                   "a21": 0.2, "a22": 0.9, "translation_x": 1.0, "translation_y": 2.0,
                   "A_2_0": 0.0001, "A_1_1": 0.0, "A_0_2": 0.0002, "B_2_0": 0.0, "B_1_1": -0.0001,
                   "B_0_2": 0.0},
}
# Required by the converter but not by the schema (names that depend on the degree).
NOT_SCHEMA_REQUIRED = {"A_2_0", "A_1_1", "A_0_2", "B_2_0", "B_1_1", "B_0_2"}


@pytest.mark.parametrize("name", SCHEMA_NAMES)
def test_valid_tree_reads(name):
    with asdf.open(yaml_to_asdf(_tagged_yaml(name, VALID_PARAMS[name]))) as af:
        model = af["model"]
    for key, value in VALID_PARAMS[name].items():
        assert getattr(getattr(model, key), "value", getattr(model, key)) == value


@pytest.mark.parametrize("name", SCHEMA_NAMES)
def test_missing_parameter_fails_validation(name):
    for missing in VALID_PARAMS[name]:
        params = {k: v for k, v in VALID_PARAMS[name].items() if k != missing}
        error = ValueError if missing in NOT_SCHEMA_REQUIRED else ValidationError
        with asdf.config_context() as config, pytest.raises(error, match=missing):
            config.warn_on_failed_conversion = False  # raise the converter's error
            with asdf.open(yaml_to_asdf(_tagged_yaml(name, params))):
                pass


@pytest.mark.parametrize("name", SCHEMA_NAMES)
@pytest.mark.parametrize("bad", [{"translation_x": "'ten'"}, {"not_a_parameter": 1.0}],
                         ids=["string-value", "unknown-property"])
def test_invalid_tree_fails_validation(name, bad):
    params = {**VALID_PARAMS[name], **bad}
    with pytest.raises(ValidationError):
        with asdf.open(yaml_to_asdf(_tagged_yaml(name, params))):
            pass


@pytest.mark.parametrize("name", ["euclidean", "similarity"])
def test_parity_must_be_plus_or_minus_one(name):
    params = {**VALID_PARAMS[name], "parity": 0.5}
    with pytest.raises(ValidationError):
        with asdf.open(yaml_to_asdf(_tagged_yaml(name, params))):
            pass


def test_validate_tree_against_schema_directly():
    schema = asdf.schema.load_schema(f"{URI_BASE}/schemas/similarity_transform-1.0.0",
                                     resolve_references=True)
    good = dict(VALID_PARAMS["similarity"])
    asdf.schema.validate(good, schema=schema)
    bad = {k: v for k, v in good.items() if k != "scale"}
    with pytest.raises(ValidationError, match="scale"):
        asdf.schema.validate(bad, schema=schema)


# -- round trips --------------------------------------------------------------


@pytest.mark.parametrize("key", list(TRANSFORMS))
def test_roundtrip_single(key, tmp_path):
    model = TRANSFORMS[key]
    result = _roundtrip(model, tmp_path)
    assert type(result) is type(model)
    # Floats are written with all their digits: parameters come back exactly.
    assert result.param_names == model.param_names
    np.testing.assert_array_equal(result.parameters, model.parameters)
    assert result.fixed == model.fixed
    assert result.inputs == model.inputs and result.outputs == model.outputs
    assert not result.has_user_inverse
    _assert_same_evaluation(model, result)
    _assert_same_evaluation(model.inverse, result.inverse)
    if "mirrored" in key:
        assert result.mirrored


def test_roundtrip_name_and_bounding_box(tmp_path):
    model = SimilarityTransform(scale=1.1, rotation=0.2 * u.rad, translation_x=3.0,
                                translation_y=4.0,
                                name="science-to-reference")
    model.bounding_box = ((0.0, 99.0), (0.0, 199.0))
    result = _roundtrip(model, tmp_path)
    assert result.name == "science-to-reference"
    assert tuple(result.bounding_box.bounding_box()) == tuple(model.bounding_box.bounding_box())


def test_roundtrip_compound_shift_concat(tmp_path):
    ours = TRANSFORMS["similarity-mirrored"]
    model = (models.Shift(1.0) & models.Shift(2.0)) | ours
    result = _roundtrip(model, tmp_path)
    leaf = result[-1]
    assert type(leaf) is SimilarityTransform
    assert leaf.parity.value == -1
    _assert_same_evaluation(model, result)
    _assert_same_evaluation(model.inverse, result.inverse)


@pytest.mark.parametrize("key", ["translation", "euclidean-mirrored", "similarity", "affine"])
def test_roundtrip_mixed_with_astropy_models(key, tmp_path):
    ours = TRANSFORMS[key]
    model = (
        (models.Shift(-0.5) & models.Scale(2.0))
        | ours
        | models.Rotation2D(angle=23.5)
        | models.AffineTransformation2D(matrix=[[1.0, 0.1], [0.0, 1.0]], translation=[3, 4])
    )
    result = _roundtrip(model, tmp_path)
    assert any(type(leaf) is type(ours) for leaf in result.traverse_postorder())
    _assert_same_evaluation(model, result)
    _assert_same_evaluation(model.inverse, result.inverse)


def test_roundtrip_user_inverse(tmp_path):
    model = SimilarityTransform(scale=1.5, rotation=0.25 * u.rad, translation_x=10.0,
                                translation_y=-5.0, parity=-1)
    # Deliberately not the analytic inverse, so we can tell them apart.
    custom = models.Rotation2D(angle=12.0) | (models.Shift(1.5) & models.Shift(-2.5))
    model.inverse = custom
    result = _roundtrip(model, tmp_path)
    assert result.has_user_inverse
    _assert_same_evaluation(model, result)
    _assert_same_evaluation(custom, result.inverse)
    # The analytic inverse is still there underneath.
    del result.inverse
    assert not result.has_user_inverse
    _assert_same_evaluation(SimilarityTransform(*model.parameters).inverse, result.inverse)


def test_roundtrip_ours_as_user_inverse_of_astropy_model(tmp_path):
    model = models.Rotation2D(angle=30.0) | (models.Shift(5.0) & models.Shift(6.0))
    ours = AffineTransform(a11=0.8, a12=0.0, a21=0.1, a22=1.2, translation_x=1.0,
                           translation_y=2.0)
    model.inverse = ours
    result = _roundtrip(model, tmp_path)
    assert type(result.inverse) is AffineTransform
    _assert_same_evaluation(ours, result.inverse)
    _assert_same_evaluation(model, result)


def test_model_set_is_rejected(tmp_path):
    model = TranslationTransform(translation_x=[1.0, 2.0], translation_y=[3.0, 4.0],
                                 n_models=2)
    with pytest.raises(ValueError, match="parameter sets"):
        asdf.AsdfFile({"obj": model}).write_to(tmp_path / "set.asdf")


# -- the non-linear models and files of the first version -----------------------------


def test_files_written_by_the_first_converters_still_read():
    """tests/data/transforms_v1.asdf was written by the asdf-astropy based converters."""
    expected = json.loads((DATA / "transforms_v1.json").read_text())
    xs = np.array([0.0, 1.0, -3.5, 123.456, 2047.0])
    ys = np.array([0.0, 2.0, 7.25, -45.5, 2047.0])
    with warnings.catch_warnings():
        # The file was written with asdf 6: an older asdf (the floor, 5.2) says so.
        warnings.simplefilter("ignore", asdf.exceptions.AsdfPackageVersionWarning)
        af = asdf.open(DATA / "transforms_v1.asdf", lazy_load=False, memmap=False)
    with af:
        used = [e["extension_uri"] for e in af["history"]["extensions"]]
        tree = {k: af[k] for k in ("translation", "euclidean", "similarity", "affine",
                                   "compound")}
    assert [uri for uri in used if "astroalign" in uri] == [OLD_EXTENSION_URI]
    for key, model in tree.items():
        assert_allclose(np.array(model(xs, ys)), expected[key], rtol=0, atol=1e-12)
    assert tree["euclidean"].name == "euclid" and tree["euclidean"].mirrored
    assert tree["similarity"].bounding_box.bounding_box() == ((0.0, 99.0), (0.0, 199.0))
    assert tree["affine"].has_user_inverse and tree["affine"].fixed["a12"]
    assert_allclose(np.array(tree["affine"].inverse(xs, ys)), expected["affine_inverse"])


def test_new_files_use_the_new_manifest(tmp_path):
    path = tmp_path / "new.asdf"
    asdf.AsdfFile({"t": TRANSFORMS["polynomial"]}).write_to(path)
    with asdf.open(path) as af:
        uris = [e["extension_uri"] for e in af["history"]["extensions"]]
    assert EXTENSION_URI in uris and OLD_EXTENSION_URI not in uris


@pytest.mark.parametrize("key", ["projective", "polynomial", "polynomial-5"])
def test_nonlinear_roundtrip_over_the_frame(key, tmp_path):
    model = TRANSFORMS[key]
    model = (models.Shift(0.25) & models.Shift(-0.5)) | model
    result = _roundtrip(model, tmp_path)
    gx, gy = np.meshgrid(np.linspace(0, 3000, 65), np.linspace(0, 2047, 33))  # both domains
    before = np.array(model(gx, gy))
    after = np.array(result(gx, gy))
    assert np.max(np.hypot(*(after - before))) < 1e-6  # pixels, the figure
    leaf = result[-1]
    assert type(leaf) is type(TRANSFORMS[key])
    if key.startswith("polynomial"):
        assert leaf.degree == TRANSFORMS[key].degree and leaf.domain == TRANSFORMS[key].domain
        assert leaf.fixed["crpix1"] and leaf.fixed["crpix2"]
        assert leaf.inverse_error == TRANSFORMS[key].inverse_error
    back = np.array(result.inverse(*after))
    assert np.max(np.hypot(back[0] - gx, back[1] - gy)) < 0.01


def test_polynomial_without_domain_and_with_constraints(tmp_path):
    model = PolynomialTransform(degree=2, crpix=(5.0, 6.0), A_2_0=1e-4, name="lens")
    model.A_1_1.fixed = True
    model.a11.bounds = (0.5, 2.0)
    model.inverse = models.Shift(-1.0) & models.Shift(-2.0)
    result = _roundtrip(model, tmp_path)
    assert result.domain is None and result.name == "lens"
    assert result.fixed["A_1_1"] and result.bounds["a11"] == (0.5, 2.0)
    _assert_same_evaluation(model, result)
    _assert_same_evaluation(model.inverse, result.inverse)


@pytest.mark.parametrize("change, message", [
    ({"degree": 7}, "degree"),
    ({"degree": 2.5}, "degree"),
    ({"A_3_0": 0.1}, "beyond its degree"),
    ({"domain": "[0.0, 1.0, 5.0, 2.0]"}, "domain"),
    ({"a11": 0.0, "a12": 0.0}, "singular"),
])
def test_damaged_polynomial_node(change, message):
    params = {**VALID_PARAMS["polynomial"], **change}
    with asdf.config_context() as config, pytest.raises(ValueError, match=message):
        config.validate_on_read = False  # the converter's own checks
        config.warn_on_failed_conversion = False
        with asdf.open(yaml_to_asdf(_tagged_yaml("polynomial", params))):
            pass


def test_singular_projective_node():
    params = {**VALID_PARAMS["projective"], "h11": 0.0, "h12": 0.0, "h13": 0.0}
    with asdf.config_context() as config, pytest.raises(ValueError, match="singular"):
        config.warn_on_failed_conversion = False
        with asdf.open(yaml_to_asdf(_tagged_yaml("projective", params))):
            pass


# -- fresh process, through the installed entry points -------------------------


def _entry_point_installed():
    return any(
        ep.name == "astroalign_nd" or ep.value.startswith("astroalign_nd.")
        for ep in importlib.metadata.entry_points(group="asdf.extensions")
    )


FRESH_SCRIPT = """
import json, sys, warnings
import asdf, numpy as np
from astropy.modeling import models
from astroalign_nd.transforms import SimilarityTransform, EuclideanTransform

warnings.simplefilter("error", asdf.exceptions.AsdfWarning)
uri = "asdf://astroalign-nd.org/astroalign_nd/extensions/astroalign_nd-1.0.0"
registered = [e for e in asdf.get_config().extensions if e.extension_uri == uri]
assert registered, "the astroalign_nd extension was not loaded from the entry points"
path = sys.argv[1]
ours = SimilarityTransform(scale=1.25, rotation=np.degrees(0.4), translation_x=7.0,
                           translation_y=-3.0, parity=-1)
model = (models.Shift(1.0) & models.Shift(2.0)) | ours | models.Rotation2D(angle=10.0)
single = EuclideanTransform(rotation=np.degrees(1.0), translation_x=2.0, translation_y=3.0)
single.inverse = models.Shift(-2.0) & models.Shift(-3.0)
asdf.AsdfFile({"model": model, "single": single}).write_to(path)
with asdf.config_context() as config:
    config.validate_on_read = True
    with asdf.open(path, lazy_load=False, memmap=False) as af:
        got = af["model"]
        got_single = af["single"]
        leaf = [type(m).__name__ for m in got.traverse_postorder()]
        x = np.array(json.loads(sys.argv[2]))
        y = np.array(json.loads(sys.argv[3]))
        out = {
            "package": registered[0].package_name,
            "leaves": leaf,
            "single": type(got_single).__name__,
            "single_user_inverse": got_single.has_user_inverse,
            "eval": np.array(got(x, y)).tolist(),
            "eval_single_inverse": np.array(got_single.inverse(x, y)).tolist(),
        }
print(json.dumps(out))
"""


@pytest.mark.skipif(
    not _entry_point_installed(),
    reason="astroalign_nd is not installed: no 'astroalign_nd' entry point in the "
    "'asdf.extensions' group (pip install -e . to run this test)",
)
def test_fresh_process_uses_entry_points(tmp_path):
    # Same interpreter, environment and working directory as this process, so
    # the subprocess sees the same installed distributions; it registers
    # nothing by hand, so asdf must find the extension through the entry points.
    proc = subprocess.run(
        [sys.executable, "-c", FRESH_SCRIPT, str(tmp_path / "fresh.asdf"),
         json.dumps(XS.tolist()), json.dumps(YS.tolist())],
        capture_output=True, text=True, cwd=os.getcwd(), env=dict(os.environ), timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["package"] == "astroalign_nd"
    assert "SimilarityTransform" in out["leaves"]
    assert out["single"] == "EuclideanTransform"
    assert out["single_user_inverse"]
    ours = SimilarityTransform(scale=1.25, rotation=np.degrees(0.4), translation_x=7.0,
                               translation_y=-3.0, parity=-1)
    model = (models.Shift(1.0) & models.Shift(2.0)) | ours | models.Rotation2D(angle=10.0)
    assert_allclose(np.array(out["eval"]), np.array(model(XS, YS)), rtol=0.0, atol=1e-9)
    inverse = models.Shift(-2.0) & models.Shift(-3.0)
    assert_allclose(np.array(out["eval_single_inverse"]), np.array(inverse(XS, YS)),
                    rtol=0.0, atol=1e-9)
