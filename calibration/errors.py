"""Errors raised by the calibration core.

Calibration code never swallows a failure: when an image cannot give a trustworthy
result (too few corners, an ambiguous pose, no mark found) it raises
:class:`CalibrationError` with a message that names the measured value and the limit.
"""
from __future__ import annotations


class CalibrationError(Exception):
    """A calibration step could not produce a trustworthy result from its input."""
