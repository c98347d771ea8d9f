"""Localization: laser odometry, visual odometry, the Kalman filter, IASM and H-IASM.

``rigcal.localize`` is also callable, a shortcut to :func:`rigcal.api.localize`; the
package ``rigcal`` makes it so (``rigcal/__init__.py``), so nothing here imports the API.
"""
