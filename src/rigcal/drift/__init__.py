"""Drift checks of a stored rig: against a new box or board session (:mod:`target`), the
drift log they append to (:mod:`log`), and the targetless check of an ordinary drive
(:mod:`targetless`), built on the localization's laser odometry and IASM's projection."""
