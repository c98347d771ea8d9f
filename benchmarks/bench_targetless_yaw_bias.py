"""Where the targetless check's photometric yaw bias comes from: one factor changed at a
time on the same seeds (docs/benchmarks.md, "The targetless check: where the photometric
term's yaw bias comes from").

With the edge term off and the simulator's true laser motion, the photometric term's yaw
correction on unmoved rigs is about -0.13 deg on every drive (round 8). Here each seed is
simulated again under ``--cache`` with one factor of the simulator changed (or checked
with one factor of the check's input changed), and the photometric term alone is
estimated on the true motion as in ``bench_targetless_photometric_alone.py --motion
true``. Printed per variant: the roll, pitch and yaw corrections' mean over the seeds and
the yaw's change against the base variant, seed by seed (paired: the same stops, camera
phase, noise and textures).

Variants of the simulation (the drive written again under ``--cache``):

- ``base``: as bench_targetless_rates (exposure walk 0.02, blur 0.7 px, noise 3);
- ``no-walk``, ``no-blur``, ``no-noise``, ``clean`` (all three off);
- ``no-distortion``: the camera without lens distortion (simulated and checked);
- ``mirrored``: the world mirrored (y -> -y): the drive turns right where it turned left;
- ``no-falloff``: the renderer's fall-off of brightness with distance off (a wall point
  then has the same brightness from every distance);
- ``clock+10ms``: the images' stamps 10 ms late (a stamp-to-exposure offset, to measure
  how the yaw answers one).

Variants of the check's input (the base drive, checked differently):

- ``cx+0.5``: the rig's principal point half a pixel to the right (a pixel-centre
  convention differing between renderer and projection by half a pixel);
- ``straight``, ``turning``: only the pairs of frames whose laser turned less than 1 deg,
  or more than 3 deg, between them;
- ``fine-blur-0.6``, ``fine-blur-2.4``: the check's last stage blurs by 0.6 or 2.4 px
  instead of 1.2 (an error that grows with the blur, such as a blurred slanted wall's
  texture pulled towards its far side, would change with it);
- ``iterations-20``: 20 Gauss-Newton iterations per stage instead of 6;
- ``odometry-held``: the laser odometry's errors (scale, yaw scale, yaw rate bias, pivot,
  crab angle), which the check estimates beside T, held at zero (right on the true
  motion); ``crab-free``: only the crab angle estimated; ``turn-free``: only the yaw
  scale and the yaw rate bias;
- ``VARIANT/held`` (VARIANT one of the simulation's): that drive, the odometry's errors
  held at zero;
- ``every``, ``every-odometry-held``: on every scan's laser odometry (as the check runs the
  photometric term alone) instead of the true motion, the odometry's errors estimated
  or held at zero.

    .venv/bin/python benchmarks/bench_targetless_yaw_bias.py --cache /tmp/ybias31/drives \\
        --seeds 300-305 --variants base,no-walk,no-blur,clean --out /tmp/ybias31/rows.jsonl
    .venv/bin/python benchmarks/bench_targetless_yaw_bias.py --cache /tmp/ybias31/drives --report \\
        --out /tmp/ybias31/rows.jsonl
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from bench_targetless import WORLDS
from bench_targetless_rates import CAMERA, read_rows, seeds_of

SIM_VARIANTS = {
    "base": {},
    "no-walk": {"exposure_walk": 0.0},
    "no-blur": {"image_blur_sigma_px": 0.0},
    "no-noise": {"image_noise_sigma": 0.0},
    "clean": {"exposure_walk": 0.0, "image_blur_sigma_px": 0.0, "image_noise_sigma": 0.0},
    "no-distortion": {},
    "mirrored": {},
    "no-falloff": {},
    "clock+10ms": {"camera_clock_offset_s": 0.010},
}
CHECK_SETTINGS: dict[str, dict[str, Any]] = {
    "fine-blur-0.6": {"blur_px": (3.0, 0.6)},
    "fine-blur-2.4": {"blur_px": (3.0, 2.4)},
    "iterations-20": {"iterations": 20},
}
HELD = 1e-9
"""The unit of an odometry error held (the check's weak prior, 10 units, then holds it at 0)."""
CHECK_NUISANCES = {
    "odometry-held": (HELD,) * 6,
    "crab-free": (HELD,) * 5 + (1e-3,),
    "turn-free": (HELD, 1e-3, 1e-3, HELD, HELD, HELD),
}
"""The units of the check's odometry errors (scale, yaw scale, yaw rate bias, pivot x and y,
crab; rigcal.drift.targetless._NUISANCE_UNITS, all 1e-3) with some held at zero."""
CHECK_VARIANTS = (
    "cx+0.5",
    "straight",
    "turning",
    *CHECK_SETTINGS,
    *CHECK_NUISANCES,
    "every",
    "every-odometry-held",
)
BASE = {"exposure_walk": 0.02, "image_blur_sigma_px": 0.7, "image_noise_sigma": 3.0}


def rig_file(cache: Path, distortion: bool, cx_shift_px: float = 0.0) -> Path:
    """The 320 x 240 simulated rig (bench_targetless_rates.small_rig), with or without its
    lens distortion, its principal point moved by ``cx_shift_px``."""
    from rigcal.camera import Camera
    from rigcal.rig import Rig
    from rigcal.rigfile import write_rig
    from rigcal.sim.box_session import default_T_cam_laser

    name = f"rig-320{'' if distortion else '-nodist'}{f'-cx{cx_shift_px:+g}' if cx_shift_px else ''}.yaml"
    path = cache / name
    if not path.exists():
        K = np.array(CAMERA["K"])
        K[0, 2] += cx_shift_px
        dist = CAMERA["dist"] if distortion else [0.0] * len(CAMERA["dist"])
        cam = Camera.from_opencv(K, dist, 320, 240, source="simulated")
        write_rig(path, Rig(default_T_cam_laser(), cam, laser={"name": "simulated 2D scanner"}))
    return path


def mirrored(world: Any) -> Any:
    """The world mirrored about its x axis (y -> -y): the same walls, textures and loop,
    driven the other way round (each surface's ends swapped, so that its texture still
    starts at the end on the viewer's left)."""
    from rigcal.sim.world import Surface

    flip = np.array([1.0, -1.0])
    surfaces = tuple(Surface(s.b * flip, s.a * flip, s.height_m, s.texture) for s in world.surfaces)
    return dataclasses.replace(world, surfaces=surfaces, path=world.path * flip)


@contextlib.contextmanager
def no_falloff() -> Iterator[None]:
    """The renderer's shading without its fall-off with distance (rigcal.sim.world_render:
    the colour divided by the same factor of the ray's length)."""
    from rigcal.sim import world_render as wr

    original = wr._shade

    def shade(world: Any, camera: Any, tex: Any, fan: Any, o: Any, R: Any, t: Any, *rest: Any) -> Any:
        out = original(world, camera, tex, fan, o, R, t, *rest)
        fall = np.clip(np.float32(1.08) - np.float32(0.02) * np.minimum(t, np.float32(1e3)), 0.7, 1.05)
        return out / fall[:, None]

    wr._shade = shade
    try:
        yield
    finally:
        wr._shade = original


def simulate(cache: Path, variant: str, world_name: str, seed: int, duration_s: float) -> tuple[Path, Path]:
    """The drive of ``variant`` (simulated once) and the rig file it is checked with."""
    from rigcal.rigfile import read_rig
    from rigcal.sim.drive import DriveSpec, write_drive
    from rigcal.sim.world import world_named

    rig_path = rig_file(cache, distortion=variant != "no-distortion")
    folder = cache / f"{variant}-{world_name}-s{seed}-{duration_s:g}s"
    if (folder / "sequence.yaml").exists():
        return folder, rig_path
    spec = DriveSpec(seed=seed, camera_rate_hz=5.0, duration_s=duration_s, **(BASE | SIM_VARIANTS[variant]))
    world = world_named(world_name)
    if variant == "mirrored":
        world = mirrored(world)
    with no_falloff() if variant == "no-falloff" else contextlib.nullcontext():
        write_drive(world, spec, str(folder), force=True, rig=read_rig(rig_path))
    return folder, rig_path


def estimate(
    folder: Path,
    rig_path: Path,
    pairs: str = "all",
    settings: dict[str, Any] | None = None,
    nuisance_units: tuple[float, ...] | None = None,
    true_motion: bool = True,
) -> dict[str, Any]:
    """The photometric term alone at the true rig on the simulator's true laser motion
    (bench_targetless_photometric_alone's ``--motion true``), on all pairs of frames or
    only those whose laser turned less than 1 deg ("straight") or more than 3 deg
    ("turning") between the two frames; with ``settings`` changed, or the odometry's
    errors' units (``nuisance_units``: tiny units hold them)."""
    from rigcal.drift import targetless as tl
    from rigcal.drift.trajectory import trajectory_odometry
    from rigcal.localize.streams import open_streams

    streams = open_streams(folder, rig_file=rig_path)
    rig = streams.rig
    assert rig is not None
    s = tl.TargetlessSettings(edges=False, **(settings or {}))
    streams.require_images("targetless check")
    if true_motion:
        streams.use_laser_odometry(trajectory_odometry(folder / "groundtruth.tum", streams))
    c = time.process_time()
    units = tl._NUISANCE_UNITS
    if nuisance_units is not None:
        tl._NUISANCE_UNITS = nuisance_units
    try:
        return _estimate(tl, rig, streams, s, pairs, c)
    finally:
        tl._NUISANCE_UNITS = units


def _estimate(tl: Any, rig: Any, streams: Any, s: Any, pairs: str, c: float) -> dict[str, Any]:
    patches = tl._build_patches(rig, streams, s)
    if pairs != "all":
        turn = np.abs(np.degrees(patches.yaw))
        keep = np.flatnonzero(turn < 1.0 if pairs == "straight" else turn > 3.0)
        patches = subset(patches, keep)
    try:
        with tl._stacks_ahead(rig, streams, patches, s):
            # The odometry's errors estimated (under the weak prior), as when this study
            # was made; its variants hold some of them through their units.
            est = tl._estimate(rig, streams, patches, s, hold_odometry=False)
    except tl._CannotTellError as exc:
        return {"cannot_tell": str(exc)}
    deg = np.degrees(est.xi[:3])
    sd = np.sqrt(np.clip(np.diag(est.cov_z), 0.0, None))[:3] * s.resolution_deg
    return {
        "rotation_deg": deg.round(4).tolist(),
        "sd_jackknife_deg": sd.round(4).tolist(),
        "translation_mm": (1000.0 * est.xi[3:5]).round(2).tolist(),
        "crab_deg": round(math.degrees(float(est.odometry[5])), 4),
        "patches": len(patches.X),
        "blocks": est.blocks,
        "cpu_s": round(time.process_time() - c, 2),
    }


def subset(patches: Any, keep: np.ndarray) -> Any:  # type: ignore[type-arg]
    """The patches ``keep`` only (their pairs and blocks keep their numbers)."""
    per_patch = ("X", "M", "img_i", "img_j", "pair", "ratio", "yaw", "dt", "block")
    blocks = np.unique(patches.block[keep])
    remap = np.full(int(patches.block.max()) + 1, -1)
    remap[blocks] = np.arange(len(blocks))
    out = dataclasses.replace(
        patches,
        **{k: getattr(patches, k)[keep] for k in per_patch},
        rows=None,
        projected=None,
        stacks_ahead={},
    )
    out.block = remap[out.block]
    return out


def pixel_centre(cache: Path) -> None:
    """Does a rendered pixel (u, v) show the world point Camera.project puts at (u, v)? Wall
    points of two corridor frames (seed 300's drive at 6 s and 12 s) are projected, the
    rendered depth is read there (bilinear, where the 2 x 4 pixels around show that wall)
    and compared with the point's depth: an offset of (e_u, e_v) pixels shows as a depth
    error e_u dZ/du + e_v dZ/dv, fitted by least squares (e_v is poorly determined: a
    vertical wall's depth hardly changes along a column)."""
    from rigcal.geometry import inv_T
    from rigcal.rigfile import read_rig
    from rigcal.sim.drive import DriveSpec, Motion, laser_poses_T
    from rigcal.sim.textures import world_textures
    from rigcal.sim.world import world_named
    from rigcal.sim.world_render import render_world

    rig = read_rig(rig_file(cache, distortion=True))
    cam = rig.camera
    world = world_named("corridor-loop")
    tex = world_textures(world, 300)
    motion = Motion(world, DriveSpec(seed=300))
    for t in (6.0, 12.0):
        T_wc = laser_poses_T(world, motion.poses(np.array([t])))[0] @ inv_T(rig.T_cam_laser)
        frame = render_world(world, cam, T_wc, tex)
        T_cw = inv_T(T_wc)
        D, S = frame.depth_m.astype(float), frame.surface
        rows = []
        for j, sf in enumerate(world.surfaces):
            a = np.linspace(0.02, 0.98, 400)[:, None]
            xy = sf.a + a * (sf.b - sf.a)
            P = np.array([[x, y, z] for x, y in xy for z in np.linspace(0.2, 2.0, 10)]) @ T_cw[:3, :3].T
            P += T_cw[:3, 3]
            P = P[P[:, 2] > 0.3]
            q = cam.project(P)
            ok = (q[:, 0] > 5) & (q[:, 0] < cam.width_px - 6) & (q[:, 1] > 5) & (q[:, 1] < cam.height_px - 6)
            for (u, v), Z in zip(q[ok], P[ok, 2], strict=True):
                u0, v0 = int(u), int(v)
                if not (S[v0 : v0 + 2, u0 - 1 : u0 + 3] == j).all():
                    continue
                fu, fv = u - u0, v - v0
                Zr = (D[v0, u0] * (1 - fu) + D[v0, u0 + 1] * fu) * (1 - fv)
                Zr += (D[v0 + 1, u0] * (1 - fu) + D[v0 + 1, u0 + 1] * fu) * fv
                rows.append((Zr - Z, D[v0, u0 + 1] - D[v0, u0], D[v0 + 1, u0] - D[v0, u0]))
        o = np.array(rows)
        e, *_ = np.linalg.lstsq(o[:, 1:], o[:, 0], rcond=None)
        rms_mm = 1000 * np.sqrt(np.mean(o[:, 0] ** 2))
        print(
            f"frame at {t:g} s: {len(o)} wall points; offset of the rendering against Camera.project: "
            f"u {e[0]:+.4f} px, v {e[1]:+.4f} px; rms depth difference {rms_mm:.2f} mm"
        )


def _last_stage_on_true_motion(folder: Path, rig_path: Path) -> tuple[Any, Any, Any, Any]:
    """The rig, the photometric term's settings (no edges), its patches on the simulator's
    true motion and the last stage's images: what --trace and --flow both start from."""
    from rigcal.drift import targetless as tl
    from rigcal.drift.trajectory import trajectory_odometry
    from rigcal.localize.streams import open_streams

    streams = open_streams(folder, rig_file=rig_path)
    rig = streams.rig
    assert rig is not None
    s = tl.TargetlessSettings(edges=False)
    streams.use_laser_odometry(trajectory_odometry(folder / "groundtruth.tum", streams))
    patches = tl._build_patches(rig, streams, s)
    images = tl._Images(streams, patches, tl._rows(rig, patches), s.blur_px[-1], s.native_blur_px)
    return rig, s, patches, images


def trace(folder: Path, rig_path: Path, iterations: int, free: str) -> None:
    """The last stage's Gauss-Newton iterations (blur 1.2 px, no trust region) from the true
    T on the true motion, with the odometry's errors ``free`` (comma-separated of scale,
    yaw-scale, yaw-rate, pivot, crab; "none"), printed every few iterations: the yaw,
    the sideways shift, the odometry's crab, the mean squared photometric residual."""
    from rigcal.drift import targetless as tl
    from rigcal.geometry import R_to_rotvec, make_T, rotvec_to_R

    rig, s, patches, images = _last_stage_on_true_motion(folder, rig_path)
    cols = [0, 1, 2, 3, 4, 6, 7, 8, 9, 10, 11]
    names = ["scale", "yaw-scale", "yaw-rate", "pivot", "pivot", "crab"]
    held = [5 + k for k, n in enumerate(names) if n not in free.split(",")]
    D = np.diag(np.r_[s.scale, tl._NUISANCE_UNITS])[np.ix_(cols, cols)]
    prior = np.eye(len(cols)) / tl.PRIOR_UNITS**2
    T0 = rig.T_cam_laser
    T, nuis = T0.copy(), np.zeros(6)
    keep = np.ones(len(cols), dtype=bool)
    for it in range(iterations + 1):
        cur = tl._evaluate(rig, T, nuis, patches, images, None, None, 6.0, cols, s)
        A_raw, g, H = tl._system(cur, tl._scales(cur), keep)
        metric = D @ H @ D + prior
        A = D @ A_raw @ D + prior + tl._held(metric)
        A[held, held] += 1e9
        if it == 0:
            C = np.linalg.inv(A)
            corr = C[2] / np.sqrt(C[2, 2] * np.diag(C))
            print(
                f"at the true T: the yaw's correlation with the sideways shift {corr[4]:+.3f}, "
                f"with the crab {corr[10]:+.3f}, the yaw rate bias {corr[7]:+.3f}"
            )
        if it % 5 == 0:
            Delta = np.linalg.inv(T0) @ T
            yaw = math.degrees(R_to_rotvec(Delta[:3, :3])[2])
            res = float((cur.r[cur.usable] ** 2).mean())
            print(
                f"iteration {it:3d}: yaw {yaw:+.4f} deg, sideways {1000 * Delta[1, 3]:+.2f} mm, crab "
                f"{math.degrees(nuis[5]):+.4f} deg, mean squared residual {res:.4f} grey^2"
            )
        d = D @ -np.linalg.solve(A, D @ g)
        T = T @ make_T(rotvec_to_R(d[:3]), np.r_[d[3:5], 0.0])
        nuis = nuis + d[5:]


def flow(folder: Path, rig_path: Path) -> None:
    """Per patch at the true T on the true motion (the last stage's images), the horizontal
    shift of frame j's samples that best aligns them with frame i's (one Gauss-Newton step
    on that shift alone, the pair's gain as the check's), averaged (weighted by the
    information) over the straight pairs (turned < 1 deg) of each gap and wall."""
    from rigcal.camera import Camera
    from rigcal.drift.sampling import project_sample

    rig, s, patches, images = _last_stage_on_true_motion(folder, rig_path)
    assert images.stack is not None
    T, cam = rig.T_cam_laser, rig.camera
    P, S, _ = patches.X.shape
    Y = patches.X @ patches.M[:, :3, :3].transpose(0, 2, 1) + patches.M[:, None, :3, 3]

    def sample(pts: np.ndarray, keys: np.ndarray, du: float = 0.0) -> np.ndarray:  # type: ignore[type-arg]
        intr = cam.intrinsics.copy()
        intr[2] += du
        c = Camera(cam.lensmodel, intr, cam.width_px, cam.height_px)
        assert images.stack is not None
        v, _, _ = project_sample(
            pts.reshape(-1, 3), T[:3, :3], T[:3, 3], c, images.stack.stack, np.repeat(keys, S), images.down,
            images.row0, images.stack.box, images.widen,
        )  # fmt: skip
        return v.reshape(P, S)

    a, b = sample(patches.X, images.key_i), sample(Y, images.key_j)
    h = 0.25
    db = (sample(Y, images.key_j, h) - sample(Y, images.key_j, -h)) / (2 * h)
    ok = np.isfinite(a).all(1) & np.isfinite(b).all(1) & np.isfinite(db).all(1)
    a0, b0 = a - a.mean(1, keepdims=True), b - b.mean(1, keepdims=True)
    db0 = db - db.mean(1, keepdims=True)
    ea = np.bincount(patches.pair, np.where(ok, (a0**2).sum(1), 0.0), patches.n_pairs)
    eb = np.bincount(patches.pair, np.where(ok, (b0**2).sum(1), 0.0), patches.n_pairs)
    gain = np.sqrt(np.where(eb > 0, ea / np.where(eb > 0, eb, 1.0), 1.0))[patches.pair][:, None]
    r, J = gain * b0 - a0, gain * db0
    info = np.where(ok, (J**2).sum(1), 0.0)
    pull = np.where(ok, (r * J).sum(1), 0.0)
    side = np.sign(patches.X[:, S // 2, 1])
    straight = np.abs(np.degrees(patches.yaw)) < 1.0
    for gap in s.gaps_s:
        G = straight & (np.abs(patches.dt - gap) < 0.5 * gap)
        cells = []
        for name, m in (("left wall", G & (side > 0)), ("right wall", G & (side < 0))):
            cells.append(
                f"{name} {-pull[m].sum() / max(info[m].sum(), 1e-12):+.4f} px ({int((m & ok).sum())})"
            )
        print(f"straight pairs {gap:g} s apart: frame j's best shift, " + ", ".join(cells))


def report(rows: list[dict[str, Any]]) -> None:
    """Per variant: the mean corrections and the yaw's paired change against ``base``."""
    by = {(r["variant"], r["seed"]): r for r in rows if "rotation_deg" in r}
    variants = list(dict.fromkeys(r["variant"] for r in rows))
    print(
        "| variant | drives | roll mean | pitch mean | yaw mean | yaw per drive "
        "| yaw - base (mean, sd of mean) |"
    )
    print("|---|---|---|---|---|---|---|")
    for v in variants:
        seeds = sorted(s for (vv, s) in by if vv == v)
        if not seeds:
            continue
        rot = np.array([by[v, s]["rotation_deg"] for s in seeds])
        diff = [
            by[v, s]["rotation_deg"][2] - by["base", s]["rotation_deg"][2] for s in seeds if ("base", s) in by
        ]
        dtxt = ""
        if diff and v != "base":
            d = np.array(diff)
            sem = float(d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else math.nan
            dtxt = f"{d.mean():+.3f} ({sem:.3f})"
        per = ", ".join(f"{y:+.3f}" for y in rot[:, 2])
        m = rot.mean(axis=0)
        print(f"| {v} | {len(seeds)} | {m[0]:+.3f} | {m[1]:+.3f} | {m[2]:+.3f} | {per} | {dtxt} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, required=True, help="where the drives are simulated (reused)")
    ap.add_argument("--seeds", default="300-305", help="a range of seeds, a-b (the world by the parity)")
    ap.add_argument(
        "--variants", default="base", help=f"comma-separated: {', '.join([*SIM_VARIANTS, *CHECK_VARIANTS])}"
    )
    ap.add_argument("--duration-s", type=float, default=24.0)
    ap.add_argument("--out", type=Path, required=True, help="JSON lines, appended (a stopped run resumes)")
    ap.add_argument("--report", action="store_true", help="only print the summary of --out")
    ap.add_argument("--pixel-centre", action="store_true", help="only the renderer-projection test")
    ap.add_argument("--trace", metavar="VARIANT", help="only trace the last stage on --seeds' first drive")
    ap.add_argument("--flow", metavar="VARIANT", help="only frame j's best shifts on --seeds' first drive")
    ap.add_argument(
        "--free", default="scale,yaw-scale,yaw-rate,pivot,crab", help="--trace: odometry errors free"
    )
    ap.add_argument("--iterations", type=int, default=60, help="--trace: iterations")
    ap.add_argument("--with", dest="also", type=Path, nargs="*", default=[], help="more rows for the summary")
    args = ap.parse_args()
    if args.pixel_centre:
        pixel_centre(args.cache)
        return
    if args.flow:
        seed = seeds_of(args.seeds)[0]
        flow(*simulate(args.cache, args.flow, WORLDS[seed % len(WORLDS)], seed, args.duration_s))
        return
    if args.trace:
        seed = seeds_of(args.seeds)[0]
        folder, rig_path = simulate(args.cache, args.trace, WORLDS[seed % len(WORLDS)], seed, args.duration_s)
        trace(folder, rig_path, args.iterations, args.free)
        return
    if not args.report:
        args.cache.mkdir(parents=True, exist_ok=True)
        done = {(r["variant"], r["seed"]) for r in read_rows(args.out)}
        for variant in args.variants.split(","):
            sim, _, held = variant.partition("/")
            if held and (held != "held" or sim not in SIM_VARIANTS):
                ap.error(f"--variants: {variant!r}: expected a simulation's variant and /held")
            if not held and variant not in SIM_VARIANTS and variant not in CHECK_VARIANTS:
                ap.error(f"--variants: {variant!r} is not one of {[*SIM_VARIANTS, *CHECK_VARIANTS]}")
            for seed in seeds_of(args.seeds):
                if (variant, seed) in done:
                    continue
                world = WORLDS[seed % len(WORLDS)]
                if sim in SIM_VARIANTS:
                    folder, rig_path = simulate(args.cache, sim, world, seed, args.duration_s)
                    units = CHECK_NUISANCES["odometry-held"] if held else None
                    row = estimate(folder, rig_path, nuisance_units=units)
                else:
                    folder, rig_path = simulate(args.cache, "base", world, seed, args.duration_s)
                    if variant == "cx+0.5":
                        row = estimate(folder, rig_file(args.cache, True, 0.5))
                    elif variant in CHECK_SETTINGS:
                        row = estimate(folder, rig_path, settings=CHECK_SETTINGS[variant])
                    elif variant.startswith("every"):
                        units = CHECK_NUISANCES["odometry-held"] if variant.endswith("held") else None
                        row = estimate(folder, rig_path, nuisance_units=units, true_motion=False)
                    elif variant in CHECK_NUISANCES:
                        row = estimate(folder, rig_path, nuisance_units=CHECK_NUISANCES[variant])
                    else:
                        row = estimate(folder, rig_path, variant)
                row = {"variant": variant, "world": world, "seed": seed} | row
                with args.out.open("a") as f:
                    f.write(json.dumps(row) + "\n")
                print(json.dumps(row), file=sys.stderr, flush=True)
    report([r for path in [args.out, *args.also] for r in read_rows(path)])


if __name__ == "__main__":
    main()
