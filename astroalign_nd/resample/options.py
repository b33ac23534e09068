# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
How the source's pixels are resampled: `ResampleConfig`, the options of
`~astroalign_nd.apply_transform`, with the interpolation orders (`ORDERS`)
and methods (`METHODS`), in the package's checking system
(``astroalign_nd.options``).
"""

import dataclasses
import numbers

import numpy as np

from ..options import Choice, check_fields, option

__all__ = ["ResampleConfig", "ORDERS", "METHODS", "order_index"]

#: The resampler's interpolation orders by name, the one table of them.
ORDERS = {"nearest-neighbor": 0, "bilinear": 1, "biquadratic": 2, "bicubic": 3}
#: The resampling methods: interpolation, or reproject's exact overlap.
METHODS = ("interpolate", "exact")


def order_index(order):
    """
    The interpolation order as an integer 0-3.

    Parameters
    ----------
    order : str or int
        One of the names in `ORDERS` or an integer from 0 to 3.

    Raises
    ------
    ValueError
        For any other value, naming the accepted ones.

    Examples
    --------
    >>> from astroalign_nd.resample import order_index
    >>> order_index("bicubic"), order_index(1)
    (3, 1)
    """
    if isinstance(order, str):
        if order in ORDERS:
            return ORDERS[order]
        if order.strip() in ("0", "1", "2", "3"):  # as the command line gives it
            return int(order)
    elif isinstance(order, numbers.Integral) and not isinstance(order, bool):
        if 0 <= int(order) <= 3:
            return int(order)
    raise ValueError(f"order must be {Order().describe()}; got {order!r}.")


class Order:
    """An interpolation order: a name of `ORDERS` or an integer 0-3 (kept as given)."""

    def describe(self):
        return f"one of {list(ORDERS)} or an integer 0-3"

    def convert(self, value):
        order_index(value)
        return value


@dataclasses.dataclass(frozen=True)
class ResampleConfig:
    """
    How the source's pixels are resampled (options of `~astroalign_nd.apply_transform`).

    Examples
    --------
    >>> from astroalign_nd.resample import ResampleConfig
    >>> ResampleConfig(order="bicubic").order
    'bicubic'
    >>> ResampleConfig(order="cubic")
    Traceback (most recent call last):
    ...
    ValueError: order must be one of ['nearest-neighbor', 'bilinear', 'biquadratic', \
'bicubic'] or an integer 0-3; got 'cubic'.
    """

    order: object = option(
        "bilinear", Order(),
        "interpolation used to resample the source: nearest-neighbor, bilinear, "
        "biquadratic or bicubic (default: %(default)s)",
        flag="--order")
    conserve_flux: bool = option(
        False, None,
        "scale the resampled values by the pixel-area change so that total flux is kept",
        flag="--conserve-flux", action="store_true")
    fill_value: float = option(
        np.nan, None,
        "value written to output pixels that have no data (outside the source's footprint, "
        "or masked); the mask marks them whatever the value. Give 0 to stack the frames "
        "with tools that do not read the mask (default: {default})",
        flag="--fill-value", type=float, metavar="VALUE", cli_default=None)
    method: str = option("interpolate", Choice(METHODS))
    parallel: bool = option(True, None)
    add_keyword: bool = option(True, None)

    def __post_init__(self):
        check_fields(self)
        # Not a field (apply_transform takes the fields as keywords): derived from order.
        object.__setattr__(self, "_order_index", order_index(self.order))

    @property
    def order_index(self):
        """The interpolation order as an integer 0-3."""
        return self._order_index
