"""The errors deepslam raises on purpose, under one root.

Catch ``DeepslamError`` to tell them from a library's own failures. Each kind also derives from the
built-in exception it refines (``ValueError`` for bad values, ``RuntimeError`` for failed work), so
code that catches those keeps working.
"""

from __future__ import annotations


class DeepslamError(Exception):
    """Root of every error deepslam raises on purpose; the message is one line naming what is wrong."""


class InputError(DeepslamError, ValueError):
    """An argument, a setting or an input value that the library cannot use."""
