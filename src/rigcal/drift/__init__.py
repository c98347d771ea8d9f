"""Drift checks that need more than a calibration method: the targetless check of a rig
from an ordinary drive, built on the localization's laser odometry and IASM's projection."""
