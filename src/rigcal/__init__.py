"""rigcal: laser-camera calibration and image-augmented laser scan matching."""

__version__ = "0.1.0"
