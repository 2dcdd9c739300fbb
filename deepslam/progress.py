"""Progress bars that keep quiet where nobody watches them."""

from __future__ import annotations

import logging
import sys

from tqdm import tqdm


def progress_bar(*args, disable: bool = False, **kwargs) -> tqdm:
    """A ``tqdm`` bar, shown only when standard error is a terminal and logging is at INFO or more
    verbose (``deepslam -q`` turns it off), and not ``disable``d by the caller."""
    hidden = disable or not sys.stderr.isatty() or logging.getLogger("deepslam").getEffectiveLevel() > logging.INFO
    return tqdm(*args, disable=hidden, dynamic_ncols=True, **kwargs)
