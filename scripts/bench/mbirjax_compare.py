#!/usr/bin/env python3
"""Forward and back projection times of mbirjax against fluidnerf's footprint projector on the
same 90-view ring, with the ratios. Not part of CI or the test command.

Geometry (the `90 x 128^2` ring of crates/classical/benches/projection.rs):
  fluidnerf: a 40 mm cube, 64^3 or 128^3 voxels; 90 pinhole cameras every 4 degrees on a circle of
  radius 360 mm around the x axis, looking at the centre, 128 x 128 px, focal length
  128 * 360 / 48 px (a 48 mm field of view at the centre, pixels of 0.375 mm there).
  mbirjax: ConeBeamModel, the same cone beam with lengths in units of one detector pixel
  projected to the rotation axis (1 ALU = 0.375 mm): source_iso_dist = 360 mm = 960 ALU, a
  flat detector at magnification 2 (source_detector_dist = 1920 ALU) with pixels of 2 ALU (so a
  detector pixel covers 1 ALU at the axis, as ours covers 0.375 mm), 128 rows x 128 channels,
  the rotation axis along the detector rows' direction as our x axis, voxels of 40 mm / n in
  ALU, recon_shape (n, n, n). Both are separable-footprint style voxel projectors on a flat
  detector; mbirjax's weights differ in detail (its own footprint model), the work per voxel
  and view is the same kind.

Timing: each projector's best of three warm runs over all 90 views (mbirjax's first call,
which compiles, is not counted); ratio = mbirjax time / fluidnerf time (above 1: fluidnerf is
faster). fluidnerf's figures come from `cargo bench -p fluidnerf-classical --bench projection --
--json` (or --ours-json FILE). Both use every core of the machine: rayon in fluidnerf, XLA's
CPU thread pool in mbirjax.
"""

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
VIEWS, PIXELS, CUBE_MM, RADIUS_MM, FOV_MM = 90, 128, 40.0, 360.0, 48.0


def ours(json_path):
    if json_path:
        return json.loads(Path(json_path).read_text())
    cmd = ["cargo", "bench", "-q", "-p", "fluidnerf-classical", "--bench", "projection", "--", "--json"]
    out = subprocess.run(cmd, cwd=REPO, check=True, capture_output=True, text=True).stdout
    line = [x for x in out.splitlines() if x.startswith("{")][-1]
    return json.loads(line)


def best_of(n, f):
    best = float("inf")
    for _ in range(n):
        t = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t)
    return best


def mbirjax_times(res):
    import jax
    import jax.numpy as jnp
    import mbirjax

    alu_mm = FOV_MM / PIXELS  # one detector pixel at the rotation axis
    sid = RADIUS_MM / alu_mm
    magnification = 2.0
    angles = jnp.linspace(0.0, 2.0 * jnp.pi, VIEWS, endpoint=False)
    model = mbirjax.ConeBeamModel(
        sinogram_shape=(VIEWS, PIXELS, PIXELS),
        angles=angles,
        source_detector_dist=magnification * sid,
        source_iso_dist=sid,
    )
    model.set_params(
        delta_det_channel=magnification,
        delta_det_row=magnification,
        delta_voxel=CUBE_MM / res / alu_mm,
        recon_shape=(res, res, res),
    )
    recon = jnp.ones((res, res, res), dtype=jnp.float32)
    sino = model.forward_project(recon)
    jax.block_until_ready(sino)
    back = model.back_project(sino)
    jax.block_until_ready(back)
    t_fwd = best_of(3, lambda: jax.block_until_ready(model.forward_project(recon)))
    t_back = best_of(3, lambda: jax.block_until_ready(model.back_project(sino)))
    return t_fwd, t_back


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ours-json", help="fluidnerf's figures from a previous `--json` run of the bench")
    ap.add_argument("--resolutions", default="64,128")
    args = ap.parse_args()
    try:
        import mbirjax  # noqa: F401
    except ImportError:
        sys.exit("mbirjax is not installed: run scripts/bench/mbirjax_compare.sh --install")
    mine = ours(args.ours_json)
    print(
        f"{VIEWS} views of {PIXELS}^2 px, cone beam; seconds for all views, best of 3; "
        f"fluidnerf on {mine.get('threads', '?')} threads"
    )
    # "ours back": one `back_add` call per view, as ASART and SART use it; "all views": one
    # `back_add_views` call for the 90 views, as MLEM uses it and as mbirjax back-projects;
    # "kept": view by view again, reading the footprints an earlier back projection kept
    # (their memory in the last column; the first, filling pass is in the bench's JSON).
    print(
        f"{'grid':>6} {'mbirjax fwd':>12} {'ours fwd':>10} {'ratio':>7} {'mbirjax back':>13} {'ours back':>10} "
        f"{'ratio':>7} {'all views':>10} {'ratio':>7} {'kept':>8} {'ratio':>7} {'MiB':>6}"
    )
    nan = float("nan")
    for res in [int(r) for r in args.resolutions.split(",")]:
        f, b = mbirjax_times(res)
        of, ob = mine[f"forward_s_{res}"], mine[f"back_s_{res}"]
        oa = mine.get(f"back_all_s_{res}", nan)
        ok, mib = mine.get(f"back_kept_s_{res}", nan), mine.get(f"kept_mib_{res}", nan)
        print(
            f"{res:>4}^3 {f:>12.3f} {of:>10.3f} {f / of:>6.1f}x {b:>13.3f} {ob:>10.3f} {b / ob:>6.1f}x "
            f"{oa:>10.3f} {b / oa:>6.1f}x {ok:>8.3f} {b / ok:>6.1f}x {mib:>6.0f}"
        )


if __name__ == "__main__":
    main()
