"""The calibration worker: runs the paper's procedures over the bus, like any client.

It measures over the bus and stores datasets; ``daemon.compute`` turns the stored
observations into results, both live and for ``ritactl recompute`` on a laptop.
"""
