# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
The package's runtime settings: `Conf`, as ``astroalign_nd.conf`` (an
astropy `~astropy.config.ConfigNamespace`, as ccdproc and photutils have):
how the package runs (threads, compiled code), the same for every call.
The options of each call (detection, matching, stacking...) are the
stages' configs instead (``astroalign_nd.config``).

Set them for the session (``astroalign_nd.conf.num_threads = 1``), for a
block (``with astroalign_nd.conf.set_temp("num_threads", 1): ...``), or in
the ``[astroalign_nd]`` section of astropy's configuration file
(``astroalign_nd.cfg`` in ``astropy.config.get_config_dir()``).
"""

import os

from astropy import config as _astropy_config

__all__ = ["Conf", "conf"]

#: The environment variable that sets ``conf.num_threads``' default; read
#: once, when the package's compiled loops are first used.
NUM_THREADS_ENV = "ASTROALIGN_ND_NUM_THREADS"
_ENV_NUM_THREADS = os.environ.get(NUM_THREADS_ENV, "").strip()


class Conf(_astropy_config.ConfigNamespace):
    """
    Configuration of astroalign_nd (``astroalign_nd.conf``).

    Examples
    --------
    >>> import astroalign_nd
    >>> with astroalign_nd.conf.set_temp("num_threads", 1):
    ...     astroalign_nd.conf.num_threads
    1
    """

    num_threads = _astropy_config.ConfigItem(
        0,
        "Threads used by the compiled loops (detection, matching, resampling). 0: the "
        f"environment variable {NUM_THREADS_ENV} if set, else every CPU this process may "
        "use. Set 1 when several worker processes share a machine.",
        cfgtype="integer", module="astroalign_nd")
    use_compiled = _astropy_config.ConfigItem(
        True,
        "Run the compiled (Cython) loops of detection, matching and resampling when they are "
        "built. "
        "False runs their NumPy versions: the same results, slower (for debugging).",
        cfgtype="boolean", module="astroalign_nd")


conf = Conf()
