"""Camera-to-robot calibration (the paper's referencing method), pure numpy/OpenCV."""

__version__ = "0.1.0"  # each result's and dataset's `software` (docs/datasets.md)
