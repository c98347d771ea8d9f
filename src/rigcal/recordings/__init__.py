"""Recordings: a drive's or a session's logs read as rigcal's data types, and imported.

The readers here build :class:`~rigcal.scan.Scan` and :class:`~rigcal.camera.Camera` from
what other tools record (ROS bags, CARMEN logs, laser text logs) and read and write
rigcal's own sequence folders (docs/formats/sequence.md); they sit above the data types
and below every method. The file-level pieces they use (YAML and text with their checks,
stamps, images, wheel odometry, atomic writes) stay in :mod:`rigcal.io`, below the data
types.
"""
