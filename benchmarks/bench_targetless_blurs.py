"""CPU time of the targetless check's blurred images alone: both stages' stacks and both
stages' edge frames, made as the check makes them for a drive (``rigcal check RIG
--sequence SEQ``), on one thread (no pool, OpenCV's own threads off), so that the
process's CPU time is theirs.

The check runs once to reach its estimate, whose arguments (the patches, the edges) are
kept; then the stages' images are made ``--repeat`` times and the least CPU time is
printed, with the pixels they hold. Run from a copy of another commit's sources (with
``PYTHONPATH=COPY/src``) for its figures: it uses only what both have
(``rigcal.drift.targetless._stack``, ``_edge_images`` or ``_edge_stack``).

    .venv/bin/python benchmarks/bench_targetless_blurs.py /work/tmp/c60
    PYTHONPATH=/tmp/before/src .venv/bin/python benchmarks/bench_targetless_blurs.py /work/tmp/c60
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import time
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import cv2


class _Inline:
    """A ThreadPoolExecutor that runs each call at once on the calling thread."""

    def __init__(self, *args: object, **kwargs: object) -> None:
        pass

    def submit(self, fn: Any, *args: Any, **kwargs: Any) -> Future[Any]:
        out: Future[Any] = Future()
        out.set_result(fn(*args, **kwargs))
        return out

    def map(self, fn: Any, *iterables: Any) -> list[Any]:
        return [fn(*x) for x in zip(*iterables, strict=False)]

    def shutdown(self, *args: object, **kwargs: object) -> None:
        pass

    def __enter__(self) -> _Inline:
        return self

    def __exit__(self, *exc: object) -> None:
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence", type=Path)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    import importlib

    import rigcal.drift.targetless as targetless
    from rigcal.localize.streams import open_streams
    from rigcal.rigfile import read_rig

    for name in ("rigcal.drift.targetless", "rigcal.drift.edges", "rigcal.drift.blur_stack"):
        with contextlib.suppress(ImportError):  # a commit without the module
            importlib.import_module(name).ThreadPoolExecutor = _Inline  # type: ignore[attr-defined]
    cv2.setNumThreads(1)
    kept: dict[str, Any] = {}

    def capture(rig: Any, streams: Any, patches: Any, s: Any) -> Any:
        kept.update(rig=rig, streams=streams, patches=patches, s=s)
        raise SystemExit  # the estimate itself is not timed

    targetless._estimate = capture  # type: ignore[assignment]
    streams = open_streams(args.sequence)
    streams.odometry_covariance = False
    with contextlib.suppress(SystemExit):
        targetless.check_targetless(read_rig(args.sequence / "rig.yaml"), streams)
    rig, streams, patches, s = kept["rig"], kept["streams"], kept["patches"], kept["s"]
    rows = targetless._rows(rig, patches)

    def stages() -> int:
        """Every stage's stack and edge frames; the pixels they hold."""
        held = 0
        for blur in s.blur_px:
            stack = targetless._stack(streams, patches, rows, blur, s.native_blur_px)[4]
            edge_blur = math.hypot(blur, s.native_blur_px)
            patches.stacks_ahead.clear()
            if hasattr(targetless, "_edge_stack"):
                edges = targetless._edge_stack(rig, patches, edge_blur, s)
                box = edges.images.box
                held += int(((box[:, 1] - box[:, 0]) * (box[:, 3] - box[:, 2])).sum())
                box = stack.box
                held += int(((box[:, 1] - box[:, 0]) * (box[:, 3] - box[:, 2])).sum())
            else:
                edges = targetless._edge_images(rig, patches, edge_blur).result()
                held += edges.stack.size + stack.size
        return held

    stages()  # the frames decoded and kept, the code warmed
    cpu = []
    for _ in range(args.repeat):
        c = time.process_time()
        held = stages()
        cpu.append(time.process_time() - c)
    print(
        json.dumps(
            {
                "sequence": str(args.sequence),
                "load": round(os.getloadavg()[0], 1),
                "blurs_cpu_s": [round(x, 3) for x in cpu],
                "least_cpu_s": round(min(cpu), 3),
                "pixels_held_millions": round(held / 1e6, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
