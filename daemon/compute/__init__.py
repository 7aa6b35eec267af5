"""The procedures' computation from stored observations: one library under both programs.

The calibration worker computes each job's result with it after measuring; ``ritactl
recompute`` and ``ritactl plate survey`` run the same code on the operator's laptop. It
sits beside the bus library, not in it (it needs numpy and OpenCV, which the thin client's
bus must not) and not in ``calibration/`` (it reads dataset folders through the bus
library's contract and writes result files, where ``calibration/`` is a pure leaf).
"""
