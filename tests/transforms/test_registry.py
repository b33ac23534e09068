# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The transform registry: every list of type names derives from it."""

import pathlib
import subprocess
import sys

import asdf
import numpy as np
import pytest
import yaml
from asdf.extension import Extension, TagDefinition
from astropy.modeling import Model

import astroalign_nd
from astroalign_nd.cli.main import build_parser
from astroalign_nd.io import transform_from_header, transform_to_header
from astroalign_nd.io.asdf import converters, extension
from astroalign_nd.matching import fit_nonlinear, match_points
from astroalign_nd.transforms import registry
from astroalign_nd.transforms import (LINEAR_TYPES, NONLINEAR_TYPES, TRANSFORM_REGISTRY,
                                      TRANSFORM_TYPES, AffineTransform, LinearTransform2D,
                                      ProjectiveTransform, SimilarityTransform, fit_transform,
                                      register_transform_type, transform_class,
                                      transform_type_of, unregister_transform_type)

from _toy_transforms import ScaleShift

BUILTIN = ("translation", "euclidean", "similarity", "affine", "projective", "polynomial")


class ToyHomography(ProjectiveTransform):
    """A toy non-linear type (a homography under another name)."""


@pytest.fixture
def scaleshift():
    entry = register_transform_type("scaleshift", ScaleShift, linear=True, conformal=True,
                                    asdf_tag="scaleshift_transform")
    yield entry
    unregister_transform_type("scaleshift")


@pytest.fixture
def toy_homography():
    yield register_transform_type("toy_homography", ToyHomography, linear=False)
    unregister_transform_type("toy_homography")


def test_builtin_lists_derive_from_the_registry():
    assert tuple(TRANSFORM_REGISTRY) == BUILTIN
    assert LINEAR_TYPES == ("translation", "euclidean", "similarity", "affine")
    assert NONLINEAR_TYPES == ("projective", "polynomial")
    assert registry.NONLINEAR_TYPES is NONLINEAR_TYPES
    assert dict(TRANSFORM_TYPES) == {n: e.cls for n, e in TRANSFORM_REGISTRY.items()}
    assert [n for n, e in TRANSFORM_REGISTRY.items() if e.parity] == ["euclidean", "similarity"]
    for name, entry in TRANSFORM_REGISTRY.items():
        assert entry.linear == issubclass(entry.cls, LinearTransform2D)
        assert entry.parity == ("parity" in entry.cls().param_names)
        assert transform_type_of(entry.cls) is entry
        assert entry.class_path == f"{entry.cls.__module__}.{entry.cls.__name__}"
    assert TRANSFORM_REGISTRY["polynomial"].degrees == astroalign_nd.transforms.polynomial.DEGREES
    assert LINEAR_TYPES + ("x",) == (*LINEAR_TYPES, "x") and "affine" in LINEAR_TYPES


def test_converters_and_manifest_match_the_registry():
    tags = [e.asdf_tag for e in TRANSFORM_REGISTRY.values()]
    assert [c.tags[0].rsplit("/", 1)[1] for c in converters.CONVERTERS] == [
        f"{t}-1.*" for t in tags]
    assert [c.types[0] for c in converters.CONVERTERS] == [
        e.class_path for e in TRANSFORM_REGISTRY.values()]
    root = pathlib.Path(extension.__file__).parent / "resources"
    manifest = yaml.safe_load((root / "manifests" / "astroalign_nd-1.1.0.yaml").read_text())
    listed = [t["tag_uri"] for t in manifest["tags"]]
    assert listed == list(extension.ASTROALIGN_ND_TAG_URIS.values())
    assert listed == [f"asdf://astroalign-nd.org/astroalign_nd/tags/{t}-1.0.0" for t in tags]
    assert list(extension.ASTROALIGN_ND_TAG_URIS) == [e.cls.__name__
                                                      for e in TRANSFORM_REGISTRY.values()]
    for tag in tags:
        assert (root / "schemas" / f"{tag}-1.0.0.yaml").is_file()


def test_cli_help_lists_the_registry_and_imports_no_model():
    sub = build_parser()._subparsers._group_actions[0].choices["register"].format_help()
    text = " ".join(sub.split())
    assert ", ".join(LINEAR_TYPES) in text and " or ".join(NONLINEAR_TYPES) in text
    code = ("import sys, astroalign_nd.cli.main; "
            "print('astropy.modeling' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.stdout.strip() == "False", out.stderr


def test_a_new_linear_type_goes_everywhere(scaleshift, tmp_path):
    assert "scaleshift" in TRANSFORM_TYPES and "scaleshift" in LINEAR_TYPES
    assert transform_class("ScaleShift") is ScaleShift and not scaleshift.parity
    truth = ScaleShift(scale=1.02, translation_x=12.5, translation_y=-7.25)
    rng = np.random.default_rng(3)
    src = rng.uniform(0, 1000, (80, 2))
    dst = np.column_stack(truth(*src.T))
    model, cov, _ = fit_transform(src, dst, "scaleshift")
    assert type(model) is ScaleShift and cov.shape == (3, 3)
    assert np.allclose(model.matrix, truth.matrix, atol=1e-9)
    # The triangle search fits it (the hypotheses are similarities: refined into the type).
    result = match_points(src, dst + rng.normal(0, 0.05, dst.shape), transform_type="scaleshift")
    assert type(result.transform) is ScaleShift
    assert abs(float(result.transform.scale.value) - 1.02) < 1e-4
    # The FITS header: its name, the matrix, the readable cards of a conformal type.
    hdr = transform_to_header(truth)
    assert hdr["AATTYPE"] == "scaleshift" and hdr["AATSCALE"] == 1.02 and hdr["AATROT"] == 0.0
    back = transform_from_header(hdr)
    assert type(back) is ScaleShift and np.array_equal(back.matrix, truth.matrix)
    # ASDF, through a converter made from the entry (an extension of its own: the
    # package's manifests list the built-in tags).
    uri = f"asdf://astroalign-nd.org/astroalign_nd/tags/{scaleshift.asdf_tag}-1.0.0"

    class ToyExtension(Extension):
        extension_uri = "asdf://example.org/toy/extensions/toy-1.0.0"
        tags = [TagDefinition(uri)]
        converters = [converters.TransformConverter.for_type(scaleshift)]

    with asdf.config_context() as config:
        config.add_extension(ToyExtension())
        asdf.AsdfFile({"t": truth}).write_to(tmp_path / "t.asdf")
        with asdf.open(tmp_path / "t.asdf") as af:
            read = af["t"]
    assert type(read) is ScaleShift and np.array_equal(read.matrix, truth.matrix)


def test_a_new_nonlinear_type(toy_homography):
    assert NONLINEAR_TYPES == ("projective", "polynomial", "toy_homography")
    assert registry.NONLINEAR_TYPES == NONLINEAR_TYPES
    model = ToyHomography(h11=1.01, h13=5.0, h31=1e-5)
    hdr = transform_to_header(model)
    assert hdr["AATTYPE"] == "toy_homography" and "AATM21" in hdr  # three rows stored
    assert type(transform_from_header(hdr)) is ToyHomography
    # Its class's parameter layer (the homography's) is what the distortion stage grows.
    src = np.random.default_rng(0).uniform(0, 1000, (100, 2))
    fit = fit_nonlinear(src, src + [2.0, -1.0], np.eye(3), transform_type="toy_homography",
                        pairs_given=True)
    assert type(fit.transform) is ToyHomography and fit.info["model"] == "toy_homography"
    assert np.allclose(fit.transform.matrix[:2, 2], [2.0, -1.0], rtol=0, atol=1e-9)


def test_a_nonlinear_type_without_a_layer_is_not_grown():
    class Bare(Model):
        n_inputs, n_outputs = 2, 2

        @staticmethod
        def evaluate(x, y):
            return x, y

    register_transform_type("bare", Bare, linear=False)
    try:
        src = np.random.default_rng(0).uniform(0, 1000, (100, 2))
        with pytest.raises(ValueError, match="grows"):  # no candidate model for it
            fit_nonlinear(src, src, np.eye(3), transform_type="bare", pairs_given=True)
    finally:
        unregister_transform_type("bare")


def test_transform_type_of():
    class MySimilarity(SimilarityTransform):
        pass

    assert transform_type_of(MySimilarity()).name == "similarity"  # its registered base
    assert transform_type_of(MySimilarity(), exact=True) is None
    assert transform_type_of(AffineTransform, exact=True).name == "affine"
    assert transform_type_of("POLYNOMIAL").name == "polynomial"
    assert transform_type_of("homography") is None and transform_type_of(np.eye(3)) is None
    assert transform_class(MySimilarity) is MySimilarity


def test_register_refuses_bad_entries(scaleshift):
    with pytest.raises(ValueError, match="registered already"):
        register_transform_type("scaleshift", AffineTransform, linear=True)
    with pytest.raises(ValueError, match="registered already"):
        register_transform_type("affine2", AffineTransform, linear=True)
    with pytest.raises(ValueError, match="lower case"):
        register_transform_type("Shear", AffineTransform, linear=True)
    with pytest.raises(ValueError, match="2 inputs"):
        register_transform_type("not_a_model", type("NotAModel", (), {}), linear=True)
    with pytest.raises(ValueError, match="built-in"):
        unregister_transform_type("similarity")
    with pytest.raises(ValueError, match="no transform type"):
        unregister_transform_type("homography")
    assert tuple(TRANSFORM_REGISTRY)[:6] == BUILTIN
