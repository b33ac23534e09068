# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""The stack's output dtype: an integer type never wraps around."""

import numpy as np
import pytest

from astroalign_nd import AstroalignWarning, stack
from astroalign_nd.simulate import simulate_sequence


@pytest.fixture(scope="module")
def frames():
    return simulate_sequence((96, 96), n_frames=3, n_stars=40, seed=5).frames


def test_sum_in_uint16_is_clipped_with_a_count(frames):
    bright = [f.copy() for f in frames]
    for f in bright:
        f.data[30:60, 30:60] = 30000.0  # three frames summed: 90,000, beyond uint16
    exact = stack(bright, method="sum", clip=None, weights=None)
    with pytest.warns(AstroalignWarning, match=r"pixels of the stack's value lie outside the "
                      r"range of uint16 \(0 to 65535\) and were clipped"):
        short = stack(bright, method="sum", clip=None, weights=None, dtype=np.uint16)
    assert short.data.dtype == np.uint16
    over = exact.data > 65535
    assert over.sum() >= 16
    assert np.all(short.data[over] == 65535)  # clipped, not wrapped around
    inside = ~over & np.isfinite(exact.data) & (exact.data >= 0)
    np.testing.assert_allclose(short.data[inside], np.rint(exact.data[inside]), atol=1)


def test_float_dtype_is_kept_and_other_types_refused(frames):
    assert stack(frames, dtype=np.float64).data.dtype == np.float64
    with pytest.raises(TypeError, match="dtype must be a real number type"):
        stack(frames, dtype=np.complex64)
    with pytest.raises(TypeError, match="dtype must be a numpy number type"):
        stack(frames, dtype="not a type")


def test_minmax_on_too_few_frames_says_it_rejects_nothing(frames):
    with pytest.warns(AstroalignWarning, match="with 2 frames none would be left, so nothing "
                      "is rejected"):
        st = stack(frames[:2], clip="minmax")
    assert st.meta["AASTKCLP"] == "none"
    assert "AASTKNLO" not in st.meta
