"""A sequence's streams as the localization methods use them, and their pairing in time.

The laser and the camera run at different rates and are not synchronised (paper Fig. 7:
"the two sensors are initially synchronized"). A method that needs the laser's points at
an image's time takes the scan nearest in time and moves its points into the laser's
frame at the image's stamp with the laser odometry between the two stamps, interpolated
(:meth:`Streams.laser_points_at_image`): nothing is dropped, and a 12 ms gap at walking
speed is not left as a centimetre of error.

Images are read from disk when asked for (grey, uint8, :func:`rigcal.io.images.read_grey`)
and kept, up to 768 MiB (the least recently used go first; :mod:`rigcal.localize.image_cache`).
The feature tracks read them in order, decoded a few frames ahead on a second thread
(:meth:`Streams.images_in_order`, :mod:`rigcal.localize.prefetch`), so that decoding
overlaps the tracking. The pairing in time is :mod:`rigcal.localize.time_pairing`'s.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Generator, Iterator
from collections.abc import Sequence as PySequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.geometry import pose_of, se2
from rigcal.io.gyro import Gyro
from rigcal.io.images import grey_of, sixteen_bit, sixteen_bit_grey, sixteen_bit_levels
from rigcal.io.stamps import outside_scans, unit_hint, within_scans
from rigcal.io.wheel_odometry import WheelOdometry, icp_starts
from rigcal.lines import Segment, extract_lines
from rigcal.localize.image_cache import Gray, ImageCache
from rigcal.localize.odometry import LASER_ODOMETRY, Odometry, icp_odometry
from rigcal.localize.prefetch import Ahead, computed_ahead
from rigcal.localize.time_pairing import nearest_index, pose_at
from rigcal.localize.tracks import FrameTracks, TrackParams, equalized, track_sequence
from rigcal.recordings.sequence import Sequence, read_sequence
from rigcal.rig import Rig
from rigcal.rigfile import read_rig
from rigcal.scan import Scan


class _StoppedError(Exception):
    """The background laser odometry was told to stop."""


@dataclass
class Streams:
    """The scans, the images and the rig of one sequence.

    Attributes:
        sequence: the sequence as read.
        rig: the rig (calibration and camera), or None when the sequence has none.
        timings_s: seconds spent per stage (filled as the stages run).
        results: stage results shared by methods (visual odometry for ``vo`` and ``kf``).
        progress: called with (stage, done, total) as long stages go on (the CLI's bars).
        track_params: the feature tracks' settings.
        odometry_covariance: whether the laser odometry computes each step's covariance
            (the Kalman filter and loop closure use them; the targetless check does not).
    """

    sequence: Sequence
    rig: Rig | None
    timings_s: dict[str, float] = field(default_factory=dict)
    _image_cache: ImageCache = field(default_factory=ImageCache, repr=False)
    _laser_odometry: Odometry | None = field(default=None, repr=False)
    _background: Future[Odometry] | None = field(default=None, repr=False)
    _background_pool: ThreadPoolExecutor | None = field(default=None, repr=False)
    _stop: threading.Event = field(default_factory=threading.Event, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _depth_lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    results: dict[str, Any] = field(default_factory=dict, repr=False)
    _lines: dict[int, list[Segment]] = field(default_factory=dict, repr=False)
    progress: Callable[[str, int, int], None] | None = field(default=None, repr=False)
    track_params: TrackParams = field(default_factory=TrackParams)
    use_wheel_odometry: bool = True
    use_gyro: bool = True
    odometry_covariance: bool = True
    _unwrapped: tuple[Odometry, FloatArray] | None = field(default=None, repr=False)

    @property
    def wheel_odometry(self) -> WheelOdometry | None:
        """The sequence's wheel odometry, unless told not to use it."""
        return self.sequence.odometry if self.use_wheel_odometry else None

    @property
    def gyro(self) -> Gyro | None:
        """The sequence's gyroscope, unless told not to use it."""
        return self.sequence.gyro if self.use_gyro else None

    def wheel_guess(self) -> FloatArray | None:
        """(N - 1, 3) the laser's motion between consecutive scans by the wheel odometry
        (NaN across a gap in it and where a scan is outside its span), or None without
        odometry."""
        return self.wheel_starts()[0]

    def wheel_starts(self) -> tuple[FloatArray | None, FloatArray | None]:
        """ICP's starts from the wheel odometry (:func:`rigcal.io.wheel_odometry.icp_starts`):
        its guesses (:meth:`wheel_guess`) and its motion across its gaps (NaN elsewhere),
        which starts ICP unless the scans contradict it, both NaN where a scan is outside
        its span; (None, None) without odometry."""
        od = self.wheel_odometry
        if od is None:
            return None, None
        t = self.scan_stamps_s
        guess, gap_guess = icp_starts(od, t)
        inside = (t >= od.stamps_s[0]) & (t <= od.stamps_s[-1])
        outside = ~(inside[:-1] & inside[1:])
        guess[outside] = np.nan
        gap_guess[outside] = np.nan
        return guess, gap_guess

    @property
    def scans(self) -> tuple[Scan, ...]:
        return self.sequence.scans

    @cached_property
    def scan_stamps_s(self) -> FloatArray:
        return np.array([s.stamp_s for s in self.sequence.scans], dtype=float)

    @property
    def image_stamps_s(self) -> FloatArray:
        return self.sequence.image_stamps_s

    @property
    def n_images(self) -> int:
        return len(self.sequence.image_files)

    def require_rig(self, method: str) -> Rig:
        """The rig, or an error saying that ``method`` needs one."""
        if self.rig is None:
            raise InputError(
                f"{self._yaml()}: no rig (key 'rig'); method {method!r} needs the calibration: "
                "add rig.yaml to the sequence or pass --rig FILE"
            )
        return self.rig

    def require_images(self, method: str, at_least: int = 2) -> None:
        """An error unless the sequence has ``at_least`` images of the rig's camera size,
        within the scans' time span."""
        if self.n_images < at_least:
            raise InputError.at(
                self._yaml(),
                "images.count",
                self.n_images,
                f"at least {at_least} images for method {method!r}",
            )
        self.require_rig(method)
        t_img, t_scan = self.image_stamps_s, self.scan_stamps_s
        if t_img[-1] < t_scan[0] or t_img[0] > t_scan[-1]:  # another clock, or another drive's images
            raise InputError.at(
                self.sequence.folder / self.sequence.image_index if self.sequence.folder else None,
                "stamp_s",
                f"{t_img[0]:.3f} to {t_img[-1]:.3f} s",
                f"images within the scans' span, {t_scan[0]:.3f} to {t_scan[-1]:.3f} s (scans.npz): "
                "the same clock" + unit_hint(t_img[-1] - t_img[0], t_scan[-1] - t_scan[0]),
            )
        self.image(0)  # its decoding checks its size against the rig's camera

    def leave_out_images_outside_scans(self) -> dict[str, int]:
        """Leave out the images stamped before the first scan or after the last by more
        than a scan period (:func:`rigcal.io.stamps.within_scans`): no scan measures the
        laser's motion there, so an image method would place them on the images alone or
        hold the scans' end pose. Returns how many were left out, ``{"before", "after"}``
        (the images kept keep their order; frames decoded before are forgotten)."""
        seq = self.sequence
        out = outside_scans(seq.image_stamps_s, self.scan_stamps_s)
        if out["before"] or out["after"]:
            keep = within_scans(seq.image_stamps_s, self.scan_stamps_s)
            files = tuple(f for f, k in zip(seq.image_files, keep, strict=True) if k)
            self.sequence = replace(seq, image_stamps_s=seq.image_stamps_s[keep], image_files=files)
            self._image_cache = ImageCache()
        return out

    def image(self, i: int) -> Gray:
        """Frame i as a grey image."""
        return self._keep(i, self._kept_or_decoded(i))

    def images_in_order(self, ahead: int = 8) -> Generator[Gray]:
        """Every frame in order, decoded ``ahead`` frames in advance on a second thread
        (OpenCV's PNG/JPEG decoding releases the interpreter, so it overlaps the work
        done on each frame). Frames already kept are not decoded again."""
        return self.images_at(range(self.n_images), ahead)

    def images_at(self, indices: PySequence[int], ahead: int = 8) -> Generator[Gray]:
        """The frames ``indices`` in that order, decoded ahead as :meth:`images_in_order`."""
        for k, g in computed_ahead(lambda k: self._kept_or_decoded(indices[k]), len(indices), ahead):
            yield self._keep(indices[k], g)

    @contextmanager
    def images_ahead(
        self, indices: PySequence[int], ahead: int, workers: int = 1
    ) -> Iterator[Iterator[Gray]]:
        """The frames ``indices`` in that order, as :meth:`images_at`, but the first
        ``ahead`` start decoding at once, on entering the context (so they decode while the
        caller does other work first, e.g. the laser odometry), on ``workers`` threads;
        leaving it stops the decoding."""
        with Ahead(lambda k: self._kept_or_decoded(indices[k]), len(indices), ahead, workers) as work:
            yield (self._keep(indices[k], g) for k, g in work)

    def _kept_or_decoded(self, i: int) -> Gray:
        hit = self._image_cache.get(i)
        return self._decode(i) if hit is None else hit

    def _decode(self, i: int) -> Gray:
        t0 = time.perf_counter()
        path = self._image_path(i)
        try:
            data = path.read_bytes()
        except OSError:
            data = b""
        wide = sixteen_bit(data)
        g = grey_of(data) if wide is None else sixteen_bit_grey(wide, self.image_depth()["shift_bits"])
        if g is None:
            raise InputError(f"{path}: not a readable image")
        if self.rig is not None and g.shape != (self.rig.camera.height_px, self.rig.camera.width_px):
            cam = self.rig.camera  # every frame, not only the first: a frame of another camera mid-drive
            raise InputError.at(
                path,
                "image size",
                f"{g.shape[1]}x{g.shape[0]}",
                f"{cam.width_px}x{cam.height_px}, the rig's camera size",
            )
        g = equalized(g, self.track_params)
        seconds = time.perf_counter() - t0
        with self._lock:
            self.timings_s["read_images_s"] = self.timings_s.get("read_images_s", 0.0) + seconds
        return g

    def image_depth(self) -> dict[str, int]:
        """The sequence's 16-bit frames (``frames``, ``max_level``, ``shift_bits``; empty:
        none), asked for when a first 16-bit frame is decoded (every frame is then looked at
        once: :func:`rigcal.io.images.sixteen_bit_levels`); each is read shifted right by
        ``shift_bits``, the rule the importers store 16-bit frames by."""
        with self._depth_lock:
            if "images_16_bit" not in self.results:
                paths = [self._image_path(i) for i in range(self.n_images)]
                self.results["images_16_bit"] = sixteen_bit_levels(paths)
            out: dict[str, int] = self.results["images_16_bit"]
            return out

    def first_image_depth(self) -> dict[str, int]:
        """:meth:`image_depth` when frame 0 is a 16-bit frame or it was found already, else
        an empty dict (frame 0's header alone is read)."""
        if "images_16_bit" not in self.results:
            try:
                wide = self.n_images > 0 and sixteen_bit(self._image_path(0).read_bytes()) is not None
            except OSError:  # its reading names it
                wide = False
            if not wide:
                return {}
        return self.image_depth()

    def _keep(self, i: int, g: Gray) -> Gray:
        """Keep frame i (the least recently used frames go when over the budget)."""
        return self._image_cache.keep(i, g)

    def laser_odometry(self) -> Odometry:
        """Point-to-line ICP over all scans (computed once; several methods share it)."""
        if self._laser_odometry is None:
            if self._background is not None:
                self._laser_odometry = self._background.result()
            else:
                self._laser_odometry = self._compute_laser_odometry()
        return self._laser_odometry

    def use_laser_odometry(self, od: Odometry) -> None:
        """Take ``od`` (one pose per scan, e.g. a trajectory computed before) as the laser
        odometry instead of computing it."""
        if len(od.poses) != len(self.scans):
            raise ValueError(f"use_laser_odometry: {len(od.poses)} poses for {len(self.scans)} scans")
        self._laser_odometry = od

    def start_laser_odometry(self) -> None:
        """Start the laser odometry on a second thread, so that it overlaps the image
        stages (feature tracking spends its time in OpenCV, which releases the
        interpreter); :meth:`laser_odometry` waits for it."""
        if self._laser_odometry is None and self._background is None:
            self._background_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="laser-odometry")
            self._background = self._background_pool.submit(self._compute_laser_odometry)

    def stop_background(self) -> None:
        """Stop the background laser odometry, if any is still running (a failed run), and
        wait for its thread to end: a command leaves no thread behind that could still
        write to stderr (a progress line, a kernel's compile note) after it returned."""
        self._stop.set()
        if self._background_pool is not None:
            self._background_pool.shutdown(wait=True)

    def _compute_laser_odometry(self) -> Odometry:
        t0 = time.perf_counter()
        n = len(self.scans)

        def progress(k: int) -> None:
            if self._stop.is_set():
                raise _StoppedError
            self.report("laser odometry", k, n)

        guess, gap_guess = self.wheel_starts()
        od = icp_odometry(
            self.scans,
            LASER_ODOMETRY["icp"],
            progress,
            self.lines,
            guess=guess,
            gap_guess=gap_guess,
            covariance=self.odometry_covariance,
        )
        self.timings_s["icp_s"] = time.perf_counter() - t0
        return od

    def lines(self, k: int) -> list[Segment]:
        """Scan k's lines. The lines of the scans nearest the images are kept, so the laser
        odometry's normals and IASM's frames share them; the others are not (a long log's
        every 4th scan would add up)."""
        segs = self._lines.get(k)
        if segs is None:
            segs = extract_lines(self.scans[k])
            if k in self._image_scans:
                self._lines[k] = segs
        return segs

    @cached_property
    def _image_scans(self) -> frozenset[int]:
        """The scans nearest an image's stamp."""
        return frozenset(self.scan_at_image(i) for i in range(self.n_images))

    def feature_tracks(self) -> list[FrameTracks]:
        """Features tracked over all images (computed once; VO and H-IASM share them)."""
        if "tracks" not in self.results:
            rig = self.require_rig("feature tracks")
            t0 = time.perf_counter()
            n = self.n_images

            def tell(k: int) -> None:
                self.report("feature tracks", k, n)

            # Closed on an error too: its decoding thread ends before the error is printed.
            with contextlib.closing(self.images_in_order()) as images:
                self.results["tracks"] = track_sequence(images, rig.camera, self.track_params, tell)
            self.timings_s["tracks_s"] = time.perf_counter() - t0
        out: list[FrameTracks] = self.results["tracks"]
        return out

    def report(self, stage: str, done: int, total: int) -> None:
        """Tell the progress callback, if any, how far a stage is."""
        if self.progress is not None:
            self.progress(stage, done, total)

    def laser_points_at_image(self, i: int) -> FloatArray:
        """(N, 2) the valid returns (in beam order) of the scan nearest image i's stamp,
        moved into the laser frame at that stamp by the interpolated laser odometry."""
        k, T_t_k = self.scan_to_image(i)
        pts = self.scans[k].points[self.scans[k].valid]
        out: FloatArray = pts @ T_t_k[:2, :2].T + T_t_k[:2, 2]
        return out

    def scan_to_image(self, i: int) -> tuple[int, FloatArray]:
        """The index k of the scan nearest image i's stamp and (3, 3) the laser's pose at
        the scan's stamp in its frame at the image's stamp (interpolated laser odometry)."""
        k = self.scan_at_image(i)
        t = float(self.image_stamps_s[i])
        return k, se2(self.odometry_motion(t, float(self.scan_stamps_s[k])))

    def scan_at_image(self, i: int) -> int:
        """The index of the scan nearest image i's stamp."""
        return nearest_index(self.scan_stamps_s, float(self.image_stamps_s[i]))

    def odometry_motion(self, t0: float, t1: float) -> FloatArray:
        """The laser's pose at t1 in its frame at t0 (x, y, yaw), from the point-to-line
        laser odometry interpolated at both stamps."""
        stamps, od = self.scan_stamps_s, self._odometry_unwrapped()
        a, b = pose_at(stamps, od, t0, unwrapped=True), pose_at(stamps, od, t1, unwrapped=True)
        return pose_of(np.linalg.inv(se2(a)) @ se2(b))

    def _odometry_unwrapped(self) -> FloatArray:
        """(N, 3) the laser odometry's poses with their yaw unwrapped (made once per odometry)."""
        od = self.laser_odometry()
        if self._unwrapped is None or self._unwrapped[0] is not od:
            poses = od.poses.copy()
            poses[:, 2] = np.unwrap(poses[:, 2])
            self._unwrapped = (od, poses)
        return self._unwrapped[1]

    def _yaml(self) -> Path | None:
        return None if self.sequence.folder is None else self.sequence.folder / "sequence.yaml"

    def _image_path(self, i: int) -> Path:
        assert self.sequence.folder is not None
        return self.sequence.folder / self.sequence.image_folder / self.sequence.image_files[i]


def require_returns(folder: str | Path, seq: Sequence) -> None:
    """Refuse a drive whose scans hold no return at all, or only the scanner's maximum."""
    # A laser unplugged, ranges in a wrong unit, or a scanner that writes its maximum range
    # for no return: nothing to localize by, however still the robot would seem to stand.
    # (A range at range_max_m is no return: rigcal.scan's rule.)
    if seq.scans and not any(s.valid.any() for s in seq.scans):
        at_max = any((s.ranges_m == s.range_max_m).any() for s in seq.scans)
        raise InputError.at(
            Path(folder),
            "scans",
            f"{'every return at range_max_m' if at_max else 'no return'} in all {len(seq.scans)} scans",
            "returns within each scan's range_min_m to range_max_m (NaN, inf, 0: no return)"
            + ("; its maximum written for no return? (import-laser --no-return-m)" if at_max else ""),
        )


def open_streams(folder: str | Path, rig_file: str | Path | None = None) -> Streams:
    """Read a sequence folder and its rig (``rig_file`` overrides the sequence's own)."""
    t0 = time.perf_counter()
    seq = read_sequence(folder)
    require_returns(folder, seq)
    rig = None
    if rig_file is not None:
        rig = read_rig(rig_file)
    elif seq.rig_file is not None:
        rig = read_rig(Path(folder) / seq.rig_file)
    return Streams(seq, rig, {"read_s": time.perf_counter() - t0})
