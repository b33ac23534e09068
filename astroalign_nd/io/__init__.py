# Licensed under a 3-clause BSD style license - see LICENSE.rst
"""
Storing transforms in files.

* FITS headers: `transform_to_header` / `transform_from_header` write and
  read a transform (linear, projective or polynomial) as ``AAT*`` keywords;
  `add_provenance` adds the fit quality (`QUALITY_KEYWORDS`) and HISTORY of
  a registration; `distorted_wcs` gives the TAN-SIP WCS of the source frame
  of a polynomial transform from the target frame's WCS.
* Writing: `write_ccddata`, `write_table` and `atomic_open` write a file
  atomically, through a file the package opened in a private folder, so an
  interrupted run never leaves half a file under the final name and nobody
  else can redirect the data; `atomic_write` gives a path instead, for
  another program.
* Output formats: a `Writer` per format (`FITSWriter` built in), found by
  the file name's ending (`writer_for`); `~astroalign_nd.register_batch`
  and the command line write, and a resumed batch reads back, through it,
  so a new output format is one writer (`register_writer`).
* ASDF: any transform, alone or inside an astropy compound model, through
  the extension in ``astroalign_nd.io.asdf`` (registered with asdf by entry
  points when the package is installed).
* A transform in a file of its own: `write_transform` / `read_transform`
  (ASDF or FITS, by the name's ending), refusing a damaged file with a
  `ValueError` that names it.
"""

from .header import QUALITY_KEYWORDS, add_provenance, transform_from_header, transform_to_header
from .sip import distorted_wcs
from .transform_files import read_transform, write_transform
from .write import atomic_open, atomic_write, write_ccddata, write_table
from .writers import (WRITERS, FITSWriter, Writer, output_suffixes, register_writer,
                      write_output, writer_for)

__all__ = ["transform_to_header", "transform_from_header", "add_provenance", "distorted_wcs",
           "QUALITY_KEYWORDS", "atomic_write", "atomic_open", "write_ccddata", "write_table",
           "read_transform",
           "write_transform", "Writer", "FITSWriter", "WRITERS", "register_writer",
           "writer_for", "output_suffixes", "write_output"]
