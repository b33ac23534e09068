"""A toy linear transform type, for the tests of adding a type (not a test module).

`ScaleShift` (``x' = s x + tx``, ``y' = s y + ty``) brings its own parameter
layer, `ScaleShiftLayer`, and nothing else: registered, it must be fitted,
matched, written, read and solved jointly like a built-in type.
"""

import numpy as np
from astropy.modeling import Parameter

from astroalign_nd.transforms import LinearTransform2D, ParameterLayer


class ScaleShiftLayer(ParameterLayer):
    """``x' = s x + tx, y' = s y + ty``: parameters ``(s, tx, ty)``."""

    name, k, affine_in_position = "scaleshift", 3, True

    def __init__(self, parity=1):
        self.parity = parity

    def design(self, q, params=None):
        d = np.zeros((len(q), 2, 3))
        d[:, 0, 0], d[:, 1, 0] = q[:, 0], q[:, 1]
        d[:, 0, 1] = d[:, 1, 2] = 1.0
        return d

    def predict(self, params, q):
        t = np.asarray(params).T
        return np.column_stack([t[0] * q[:, 0] + t[1], t[0] * q[:, 1] + t[2]])

    def to_parts(self, params):
        return params[0] * np.eye(2), params[1:]

    def from_parts(self, lin, shift):
        return np.array([(lin[0, 0] + lin[1, 1]) / 2.0, *shift])

    def area(self, params):
        s = params[:, 0]
        return s ** 2, -s[:, None]  # det = s^2; d log(1/|s|) / ds, times det


class ScaleShift(LinearTransform2D):
    """A toy linear type: uniform scale and shift, without rotation."""

    scale = Parameter(default=1.0)
    translation_x = Parameter(default=0.0)
    translation_y = Parameter(default=0.0)
    min_points = 2
    n_dof = 3
    _layer = ScaleShiftLayer

    @staticmethod
    def evaluate(x, y, scale, translation_x, translation_y):
        return scale * x + translation_x, scale * y + translation_y

    @property
    def rotation(self):
        return 0.0

    @classmethod
    def _from_matrix(cls, m):
        # A jointly solved matrix carries a rotation of rounding size: 1e-6, not zero.
        if not np.allclose(m[:2, :2], m[0, 0] * np.eye(2), rtol=0.0, atol=1e-6):
            raise ValueError("matrix is not a uniform scale without rotation")
        return cls(scale=m[0, 0], translation_x=m[0, 2], translation_y=m[1, 2])
