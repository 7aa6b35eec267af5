"""The calibration worker: runs the paper's procedures over the bus, like any client.

It is the one part of ``calibration/`` that does I/O: bus calls, dataset files and
reports. The math stays in the pure modules next to it; ``compute`` turns stored
observations into results, both live and for ``ritactl recompute``.
"""
