#!/usr/bin/env python3
"""PyTorch-CPU reference of the faithful FluidNeRF reconstruction, for whole-run comparisons.

`fluidnerf reconstruct -m fluidnerf` trains the dissertation's network with a hand-written CPU
engine. This script trains the same model on the same scene with PyTorch, so that volume NRMSE
against training wall time can be compared run against run: the engines differ, the algorithm
does not. What is replicated (crates/neural/src, see docs/training-engine.md):

- Scene (crates/io/src/scene.rs): nerfstudio `transforms.json`, intrinsics at the top level or
  per frame, `cx, cy` measured from the image corner (pixel centres are integers after
  subtracting 0.5), OpenGL camera-to-world poses (`R_cv = R_gl diag(1, -1, -1)`), our keys
  `aabb`, `intensity_scale`, `truth`, `holdout`, `thin_lens`. Images: 8/16-bit PNG or TIFF,
  raw counts as float (Pillow). Truth: `.npy` of shape (nz, ny, nx) filling the aabb.
  OpenCV distortion (k1 k2 k3 p1 p2 and the rational opencv_k4..k6) is inverted per pixel by
  Newton's method to 1e-6 px, as `Camera::unproject_normalised`; nerfstudio's k4 (an r^8 term)
  is refused, as ours does. A `thin_lens` is accepted because the emission weight of Eq. 5.3
  relative to the focal plane, (l_o/s)^2 (p s/l_i)^2 / (p l_o/l_i)^2, is identically 1
  (crates/neural/src/render.rs).
- Rays (sampling.rs): one per pixel centre, clipped to the box (slab method, s >= 0, in float64,
  then float32); rays missing the box are dropped. Points handed to the field are box-unit
  `u = (o - min)/size + s d/size`.
- Normalisation (train.rs): pixels / image_scale (the largest training pixel); quadrature
  distances / L (the longest box side); the field learns e = E / value_scale with
  value_scale = image_scale / (intensity_scale L).
- One iteration: N_pix/img pixels drawn with replacement from every training image; stratified
  samples (Eq. 5.1); with N_f > 0 the coarse field without gradients, N_f feature samples from
  the PDF |E_{j+1} - E_j| + 1 % uniform floor by inverse CDF at stratified quantiles, merged;
  the field at all N_c + N_f samples; trapezoid quadrature (Eq. 5.4) with the end pieces
  (`close_ends`); MSE (Eq. 5.5); Adam (0.9, 0.999, eps 1e-7) with lr(i) = 5e-4 (0.1)^(i/25000).
- Network (mlp.rs, encoding.rs): gamma(tau) per coordinate [tau, sin 2^k pi tau, cos 2^k pi tau]
  with tau = 2u - 1 and L = 8 (phases reduced exactly, as ours), 8 x 256 ReLU, layer 4 takes
  [h, gamma(x)], softplus output; He-uniform hidden weights, Glorot-uniform output weights,
  zero biases; then the uniform start (train.rs `Learner::fresh`): output bias =
  softplus^-1(mean level), output weights x 0.1, mean level = sum of targets / sum of
  normalised chord lengths.
- Stopping (train.rs): max iterations, time budget (training time), the section 5.1.5 rule
  (running mean over 200 iterations changing < 2 % across 2000).
- NRMSE curve (crates/cli/src/commands/reconstruct_neural.rs `TruthSample`): every k-th voxel
  centre of the truth, k = max over axes of ceil(n / 64), from k // 2; field x value_scale;
  NRMSE = sqrt(sum (E - E_true)^2 / sum E_true^2). Evaluation time is excluded from the
  training time, as ours.
- Held-out views: MSE over a fixed random subset of 4096 held-out pixels every 100
  iterations, counted in the training time (as ours).

Randomness comes from torch generators seeded with --seed: runs are reproducible for a given
thread count, but not bit-identical to the Rust engine's (different random streams).

Engine choices (what a PyTorch user would write on a CPU): batched tensors throughout, the
coarse pass under torch.inference_mode, the rays of an iteration processed in chunks of
--chunk-rays with gradients accumulated (the full batch of 15 x 1024 rays x 128 samples would
need ~16 GB of activations), torch.optim.Adam with fused=True (the fastest CPU Adam in torch).

Usage:
  python3 pytorch_faithful.py SCENE_DIR --out report.json [--preset ch7] [--rays-per-image 1024]
      [--coarse-samples 64] [--fine-samples 64] [--time-budget S] [--max-iterations N]
      [--eval-every N] [--threads 2] [--seed 0] [--chunk-rays 1024]
  python3 pytorch_faithful.py --self-test [SCENE_DIR]

The report holds the field names of `fluidnerf reconstruct`'s report.json (method, preset,
nrmse_history [{iteration, train_time_s, nrmse}], loss_history, holdout_loss_history, train
{...}, cpu_s, final_nrmse, ...) plus seconds_per_iteration, torch_version, threads and the
resolved settings.
"""

import argparse
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

SCRIPT_VERSION = "1"
METHOD = "pytorch-fluidnerf"

# Sample counts of the named presets of crates/neural/src/trained.rs (MLP presets only).
PRESETS = {"faithful": (128, 128), "ch7": (64, 64)}
PDF_UNIFORM_FLOOR = 0.01
UNIFORM_START_WEIGHT_SCALE = 0.1
INTRINSIC_KEYS = (
    "camera_model",
    "w",
    "h",
    "fl_x",
    "fl_y",
    "cx",
    "cy",
    "k1",
    "k2",
    "k3",
    "k4",
    "p1",
    "p2",
    "skew",
    "opencv_k4",
    "opencv_k5",
    "opencv_k6",
)
PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "SIMPLE_RADIAL", "RADIAL", "FULL_OPENCV")


class SceneError(Exception):
    """A scene this script cannot use; the message names the file and the problem."""


# ----------------------------------------------------------------------------------------------
# Scene loading (crates/io)


def read_image(path):
    """A PNG or TIFF as float32 (h, w) raw counts; colour is reduced to Rec. 709 luminance."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            if im.mode in ("RGB", "RGBA", "LA", "P"):
                rgb = np.asarray(im.convert("RGB") if im.mode == "P" else im, dtype=np.float32)
                if rgb.ndim == 3 and rgb.shape[2] >= 3:
                    return rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722
                return rgb[..., 0]
            return np.asarray(im, dtype=np.float32)
    except (OSError, ValueError) as e:
        raise SceneError(f"{path}: unreadable image ({e})") from e


def distort(x, y, dist):
    """OpenCV's model (`Distortion::apply_with_jacobian`): distorted normalised coordinates and
    the Jacobian (dxx, dxy, dyx, dyy) of undistorted (x, y), arrays of any shape."""
    k1, k2, p1, p2, k3, k4, k5, k6 = (dist[k] for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"))
    r2 = x * x + y * y
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    a = num / den
    da = ((k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)) * den - num * (k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2))) / (
        den * den
    )
    xd = x * a + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * a + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    cross = 2.0 * x * y * da + 2.0 * p1 * x + 2.0 * p2 * y
    jac = (
        a + 2.0 * x * x * da + 2.0 * p1 * y + 6.0 * p2 * x,
        cross,
        cross,
        a + 2.0 * y * y * da + 6.0 * p1 * y + 2.0 * p2 * x,
    )
    return xd, yd, jac


def undistort(xd, yd, dist, tol):
    """Inverts `distort` by damped Newton steps (`Camera::unproject_normalised`): each point stops
    once it re-distorts to within `tol` (normalised units); None if some point does not."""
    x, y = xd.copy(), yd.copy()
    active = np.ones(x.shape, dtype=bool)
    for _ in range(100):
        ex, ey, (dxx, dxy, dyx, dyy) = distort(x, y, dist)
        rx, ry = ex - xd, ey - yd
        active &= np.hypot(rx, ry) >= tol
        if not active.any():
            return x, y
        det = dxx * dyy - dxy * dyx
        if not np.all(np.isfinite(det[active]) & (np.abs(det[active]) >= 1e-12)):
            return None
        sx = (dyy * rx - dxy * ry) / det
        sy = (-dyx * rx + dxx * ry) / det
        # Damp steps that would leave the region where the model is monotone.
        length = np.hypot(sx, sy)
        limit = 0.5 * (1.0 + np.hypot(x, y))
        damp = np.where(length > limit, limit / np.where(length > 0, length, 1.0), 1.0)
        x = np.where(active, x - sx * damp, x)
        y = np.where(active, y - sy * damp, y)
    return None


def pixel_rays(cam, aabb_min, aabb_max):
    """Rays of every pixel centre of `cam` clipped to the box, as in `ImageRays::new`.

    Returns (origin_unit (3,), dir_unit (n, 3), near (n,), far (n,), pixel (n,)) with
    origin_unit = (o - min) / size, dir_unit = d / size (d unit, world), near/far world
    distances; float32 except pixel (int64, row * w + col), and the number of rays on the box.
    """
    w, h = cam["w"], cam["h"]
    col, row = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    col, row = col.ravel(), row.ravel()
    # Camera::unproject_normalised (skew acts on x).
    yn = (row - cam["cy"]) / cam["fy"]
    xn = (col - cam["cx"] - cam["skew"] * yn) / cam["fx"]
    if any(v != 0.0 for v in cam["dist"].values()):
        xy = undistort(xn, yn, cam["dist"], 1e-6 / max(cam["fx"], cam["fy"]))
        if xy is None:
            raise SceneError(f"{cam['name']}: undistortion of the pixel grid did not converge")
        xn, yn = xy
    d_cam = np.stack([xn, yn, np.ones_like(xn)], axis=1)
    d = d_cam @ cam["R"].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = cam["t"]
    near = np.zeros(len(d))
    far = np.full(len(d), np.inf)
    hit = np.ones(len(d), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for a in range(3):
            da = d[:, a]
            par = da == 0.0
            inside = (o[a] >= aabb_min[a]) & (o[a] <= aabb_max[a])
            hit &= ~par | inside
            t0 = (aabb_min[a] - o[a]) / da
            t1 = (aabb_max[a] - o[a]) / da
            lo, hi = np.minimum(t0, t1), np.maximum(t0, t1)
            near = np.where(par, near, np.maximum(near, lo))
            far = np.where(par, far, np.minimum(far, hi))
    hit &= near < far
    size = aabb_max - aabb_min
    origin_unit = ((o - aabb_min) / size).astype(np.float32)
    dir_unit = (d[hit] / size).astype(np.float32)
    pixel = np.nonzero(hit)[0].astype(np.int64)
    return origin_unit, dir_unit, near[hit].astype(np.float32), far[hit].astype(np.float32), pixel


def load_scene(scene_dir):
    """Reads transforms.json, the images and the truth (if any) of `scene_dir`."""
    path = scene_dir if scene_dir.endswith(".json") else os.path.join(scene_dir, "transforms.json")
    root = os.path.dirname(os.path.abspath(path))
    try:
        with open(path) as f:
            raw = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise SceneError(f"{path}: cannot read the scene file ({e})") from e
    if "aabb" not in raw:
        raise SceneError(f"{path}: no `aabb` (the reconstruction box) in the scene file")
    aabb = np.asarray(raw["aabb"], dtype=np.float64)
    if aabb.shape != (2, 3) or not np.all(aabb[1] > aabb[0]):
        raise SceneError(f"{path}: `aabb` must be [[min x, y, z], [max x, y, z]] with max > min")
    intensity_scale = float(raw.get("intensity_scale", 1.0))
    if not (intensity_scale > 0 and math.isfinite(intensity_scale)):
        raise SceneError(f"{path}: intensity_scale must be positive, got {intensity_scale}")
    frames = raw.get("frames") or []
    if not frames:
        raise SceneError(f"{path}: no frames")
    resolve = lambda p: p if os.path.isabs(p) else os.path.join(root, p)  # noqa: E731
    views = []
    for i, fr in enumerate(frames):
        k = {key: fr.get(key, raw.get(key)) for key in INTRINSIC_KEYS}
        name = fr.get("file_path", "?")
        where = f"{path}: frame {i} ({name})"
        model = k["camera_model"] or "OPENCV"
        if model not in PINHOLE_MODELS:
            raise SceneError(f"{where}: camera_model {model} is not supported")
        missing = [key for key in ("w", "h", "fl_x", "fl_y", "cx", "cy") if k[key] is None]
        if missing:
            raise SceneError(f"{where}: {', '.join(missing)} given neither at the top level nor in the frame")
        if k["k4"] not in (None, 0, 0.0):
            raise SceneError(
                f"{where}: k4 is nerfstudio's r^8 radial term, which the OpenCV model does not have; "
                "use 0 (OpenCV's rational k4 is `opencv_k4`)"
            )
        m = np.asarray(fr["transform_matrix"], dtype=np.float64)
        if m.shape != (4, 4) or not np.allclose(m[3], [0, 0, 0, 1]):
            raise SceneError(f"{where}: transform_matrix must be 4 x 4 with last row [0, 0, 0, 1]")
        cam = {
            "w": int(k["w"]),
            "h": int(k["h"]),
            "fx": float(k["fl_x"]),
            "fy": float(k["fl_y"]),
            # nerfstudio measures cx, cy from the image corner; ours from the first pixel centre.
            "cx": float(k["cx"]) - 0.5,
            "cy": float(k["cy"]) - 0.5,
            "skew": float(k["skew"] or 0.0),
            "dist": {
                "k1": float(k["k1"] or 0.0),
                "k2": float(k["k2"] or 0.0),
                "k3": float(k["k3"] or 0.0),
                "p1": float(k["p1"] or 0.0),
                "p2": float(k["p2"] or 0.0),
                "k4": float(k["opencv_k4"] or 0.0),
                "k5": float(k["opencv_k5"] or 0.0),
                "k6": float(k["opencv_k6"] or 0.0),
            },
            "name": where,
            # OpenGL camera axes -> OpenCV: negate the second and third columns.
            "R": m[:3, :3] * np.array([1.0, -1.0, -1.0]),
            "t": m[:3, 3].copy(),
        }
        img_path = resolve(name)
        image = read_image(img_path)
        if image.shape != (cam["h"], cam["w"]):
            raise SceneError(
                f"{img_path}: image is {image.shape[1]}x{image.shape[0]} but its camera is {cam['w']}x{cam['h']}"
            )
        if not np.all(np.isfinite(image)):
            raise SceneError(f"{img_path}: non-finite pixels")
        views.append({"camera": cam, "image": image, "holdout": bool(fr.get("holdout", False)), "name": name})
    truth = None
    if raw.get("truth"):
        if len(raw["truth"]) > 1:
            print(f"{path}: {len(raw['truth'])} truth volumes; using the first", file=sys.stderr)
        tpath = resolve(raw["truth"][0]["file_path"])
        try:
            truth = np.load(tpath).astype(np.float32)
        except (OSError, ValueError) as e:
            raise SceneError(f"{tpath}: cannot read the truth volume ({e})") from e
        if truth.ndim != 3 or not np.all(np.isfinite(truth)):
            raise SceneError(f"{tpath}: the truth must be a finite (nz, ny, nx) array")
    return {"aabb": aabb, "intensity_scale": intensity_scale, "views": views, "truth": truth, "file": path}


# ----------------------------------------------------------------------------------------------
# Model (crates/neural/src/encoding.rs, mlp.rs)


def build_field(torch, depth, width, freqs, seed):
    nn = torch.nn
    enc_dim = 3 * (1 + 2 * freqs)
    skip = depth // 2 if depth >= 2 else None

    class FaithfulField(nn.Module):
        """gamma(x) -> D x H ReLU (layer D/2 takes [h, gamma]) -> softplus; input box-unit u."""

        def __init__(self):
            super().__init__()
            self.layers = nn.ModuleList()
            for k in range(depth):
                fan_in = (enc_dim if k == 0 else width) + (enc_dim if k == skip else 0)
                self.layers.append(nn.Linear(fan_in, width))
            self.output = nn.Linear(width, 1)
            self.register_buffer("scales", 2.0 ** torch.arange(freqs, dtype=torch.float32), persistent=False)

        def encode(self, u):
            tau = 2.0 * u - 1.0
            p = tau[..., None] * self.scales  # exact: powers of two
            ph = math.pi * (p - 2.0 * torch.round(0.5 * p))
            sc = torch.stack([torch.sin(ph), torch.cos(ph)], dim=-1).flatten(-2)
            return torch.cat([tau[..., None], sc], dim=-1).flatten(-2)

        def forward(self, u):
            g = self.encode(u)
            h = g
            for k, lin in enumerate(self.layers):
                if k == skip:
                    h = torch.cat([h, g], dim=-1)
                # In place: addmm's backward needs its inputs, not its output.
                h = torch.relu_(lin(h))
            return torch.nn.functional.softplus(self.output(h)).squeeze(-1)

    field = FaithfulField()
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for lin in field.layers:
            a = math.sqrt(6.0 / lin.in_features)
            lin.weight.uniform_(-a, a, generator=gen)
            lin.bias.zero_()
        a = math.sqrt(6.0 / (width + 1))
        field.output.weight.uniform_(-a, a, generator=gen)
        field.output.bias.zero_()
    return field


def inverse_softplus(e):
    return e + math.log1p(-math.exp(-e)) if e > 20.0 else math.log(math.expm1(e))


def start_uniform(torch, field, level):
    """`MlpField::start_uniform`: the field starts near `level` everywhere."""
    with torch.no_grad():
        field.output.bias.fill_(inverse_softplus(level))
        field.output.weight.mul_(UNIFORM_START_WEIGHT_SCALE)


# ----------------------------------------------------------------------------------------------
# Sampling and rendering (crates/neural/src/sampling.rs, render.rs), batched over rays


def stratified(torch, near, far, n, gen):
    """Eq. 5.1: n equal bins on [near, far], one uniform sample each. near, far: (R,)."""
    step = (far - near) / n
    u = torch.rand(near.shape[0], n, generator=gen)
    i = torch.arange(n, dtype=torch.float32)
    return torch.minimum(near[:, None] + (i + u) * step[:, None], far[:, None])


def feature_samples(torch, s, e, n, gen):
    """n sorted samples per ray from the PDF |E_{j+1} - E_j| (+ uniform floor) by inverse CDF at
    stratified quantiles (i + U_i) / n. s, e: (R, N_c) sorted samples and coarse values."""
    ds = s[:, 1:] - s[:, :-1]
    de = (e[:, 1:] - e[:, :-1]).abs()
    total = de.sum(-1, keepdim=True)
    span = s[:, -1:] - s[:, :1]
    ok = (total > 0) & (span > 0)
    floor = torch.where(
        ok, PDF_UNIFORM_FLOOR / (1.0 - PDF_UNIFORM_FLOOR) * total / torch.where(ok, span, 1.0), 1.0
    )
    mass = de + floor * ds
    norm = mass.sum(-1, keepdim=True)
    pdf = mass / norm
    cdf = torch.cumsum(pdf, -1)
    cdf_lo = torch.nn.functional.pad(cdf[:, :-1], (1, 0))
    q = ((torch.arange(n, dtype=torch.float32) + torch.rand(s.shape[0], n, generator=gen)) / n).clamp(max=1.0)
    j = torch.searchsorted(cdf, q).clamp(max=s.shape[1] - 2)
    m = pdf.gather(1, j)
    t = torch.where(m > 0, ((q - cdf_lo.gather(1, j)) / m).clamp(0.0, 1.0), 0.5)
    s0 = s.gather(1, j)
    out = s0 + t * (s.gather(1, j + 1) - s0)
    good = (norm > 0) & torch.isfinite(norm)
    return torch.where(good, out, s[:, :1])


def quadrature_weights(torch, s, near, far, scale, close_ends=True):
    """Eq. 5.4 trapezoid weights w (R, N) with pixel = sum_j w_j E_j; pinhole (Omega A = 1)."""
    half = 0.5 * (s[:, 1:] - s[:, :-1]) * scale
    pad = torch.nn.functional.pad
    w = pad(half, (0, 1)) + pad(half, (1, 0))
    if close_ends:
        lead = (s[:, 0] - near).clamp(min=0.0) * scale
        tail = (far - s[:, -1]).clamp(min=0.0) * scale
        w = w + pad(lead[:, None], (0, s.shape[1] - 1)) + pad(tail[:, None], (s.shape[1] - 1, 0))
    return w


def points(o, d, s):
    """Box-unit points u = o + s d: o, d (R, 3), s (R, N) -> (R, N, 3)."""
    return o[:, None, :] + s[..., None] * d[:, None, :]


def sample_ray_batch(torch, field, o, d, near, far, nc, nf, scale, gen):
    """Sample positions and quadrature weights of a chunk of rays (no gradients)."""
    with torch.inference_mode():
        s = stratified(torch, near, far, nc, gen)
        if nf > 0:
            e = field(points(o, d, s))
            s = torch.sort(torch.cat([s, feature_samples(torch, s, e, nf, gen)], dim=1), dim=1).values
        w = quadrature_weights(torch, s, near, far, scale)
    # Inference tensors cannot be saved for backward; these are plain inputs from here on.
    return s.clone(), w.clone()


# ----------------------------------------------------------------------------------------------
# Training data (train.rs `Prepared`)


class Prepared:
    def __init__(self, torch, scene):
        aabb = scene["aabb"]
        self.length = float((aabb[1] - aabb[0]).max())
        train = [v for v in scene["views"] if not v["holdout"]]
        holdout = [v for v in scene["views"] if v["holdout"]]
        if not train:
            raise SceneError(f"{scene['file']}: no training images")
        self.image_scale = float(max(v["image"].max() for v in train))
        if not self.image_scale > 0:
            raise SceneError(f"{scene['file']}: all training images are black")
        self.value_scale = self.image_scale / (scene["intensity_scale"] * self.length)
        self.train = self._rays(torch, train, aabb)
        self.holdout = self._rays(torch, holdout, aabb) if holdout else None
        if self.train["n"] == 0:
            raise SceneError(f"{scene['file']}: no camera sees the reconstruction box")
        t = self.train
        self.mean_level = float(
            t["target"].double().sum() / ((t["far"] - t["near"]).double().sum() / self.length)
        )

    def _rays(self, torch, views, aabb):
        o, d, near, far, target, counts = [], [], [], [], [], []
        for v in views:
            ou, du, n, f, px = pixel_rays(v["camera"], aabb[0], aabb[1])
            o.append(np.broadcast_to(ou, du.shape))
            d.append(du)
            near.append(n)
            far.append(f)
            target.append(v["image"].ravel()[px] / np.float32(self.image_scale))
            counts.append(len(n))
        cat = lambda xs: torch.from_numpy(np.ascontiguousarray(np.concatenate(xs)).astype(np.float32))  # noqa: E731
        counts = torch.tensor(counts, dtype=torch.int64)
        return {
            "o": cat(o),
            "d": cat(d),
            "near": cat(near),
            "far": cat(far),
            "target": cat(target),
            "counts": counts,
            "offsets": torch.cumsum(counts, 0) - counts,
            "n": int(counts.sum()),
        }


# ----------------------------------------------------------------------------------------------
# Truth sampling (reconstruct_neural.rs `TruthSample`)


def truth_points(truth, aabb, stride=None):
    """Box-unit voxel centres every `stride`-th voxel per axis from stride // 2 (stride default
    max ceil(n / 64)), and the truth there. truth: (nz, ny, nx)."""
    nz, ny, nx = truth.shape
    if stride is None:
        stride = max(max(-(-n // 64) for n in (nx, ny, nz)), 1)
    ks, js, iis = (np.arange(stride // 2, n, stride) for n in (nz, ny, nx))
    k, j, i = np.meshgrid(ks, js, iis, indexing="ij")
    dims = np.array([nx, ny, nz], dtype=np.float64)
    # World centre then box-unit, as Volume::voxel_centre and WorldField (f32 there).
    size = aabb[1] - aabb[0]
    world = aabb[0] + (np.stack([i, j, k], axis=-1).reshape(-1, 3) + 0.5) * (size / dims)
    u = ((world - aabb[0]) / size).astype(np.float32)
    return u, truth[k.ravel(), j.ravel(), i.ravel()]


def field_values(torch, field, u, chunk=65536):
    out = torch.empty(u.shape[0])
    with torch.inference_mode():
        for a in range(0, u.shape[0], chunk):
            out[a : a + chunk] = field(u[a : a + chunk])
    return out


def nrmse(est, truth):
    est, truth = est.astype(np.float64), truth.astype(np.float64)
    energy = float((truth**2).sum())
    return math.sqrt(float(((est - truth) ** 2).sum()) / energy) if energy > 0 else float("nan")


def ssim_global(a, b, data_range):
    """Eq. 6.19 over the whole arrays as one window (fluidnerf_metrics::ssim_global)."""
    a, b = a.astype(np.float64), b.astype(np.float64)
    ma, mb = a.mean(), b.mean()
    va, vb, cov = ((a - ma) ** 2).mean(), ((b - mb) ** 2).mean(), ((a - ma) * (b - mb)).mean()
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    return float((2 * ma * mb + c1) * (2 * cov + c2) / ((ma * ma + mb * mb + c1) * (va + vb + c2)))


# ----------------------------------------------------------------------------------------------
# Training (train.rs `train`)


def running_mean(values, n):
    tail = values[-n:] if n > 0 else values
    return sum(tail) / len(tail) if tail else float("nan")


def converged(losses, smoothing=200, window=2000, tolerance=0.02):
    if window == 0 or len(losses) < window + smoothing:
        return False
    now = running_mean(losses, smoothing)
    then = running_mean(losses[: len(losses) - window], smoothing)
    return then > 0 and abs((now - then) / then) < tolerance


def render_loss(torch, field, rays, idx, args, scale, gen, n_pix, with_grad):
    """Renders rays[idx] in chunks; with_grad accumulates d(loss)/d(params). Returns the loss
    sum over these rays of (I - I_meas)^2 / n_pix."""
    total = 0.0
    for a in range(0, idx.shape[0], args.chunk_rays):
        ci = idx[a : a + args.chunk_rays]
        o, d = rays["o"][ci], rays["d"][ci]
        near, far, target = rays["near"][ci], rays["far"][ci], rays["target"][ci]
        s, w = sample_ray_batch(
            torch, field, o, d, near, far, args.coarse_samples, args.fine_samples, scale, gen
        )
        if with_grad:
            pixel = (w * field(points(o, d, s))).sum(-1)
            loss = ((pixel - target) ** 2).sum() / n_pix
            loss.backward()
        else:
            with torch.inference_mode():
                pixel = (w * field(points(o, d, s))).sum(-1)
                loss = ((pixel - target) ** 2).sum() / n_pix
        total += loss.item()
    return total


def train(torch, field, prep, truth, aabb, args, settings):
    scale = 1.0 / prep.length
    lr0, lr1, decay = 5e-4, 5e-5, 25_000
    opt_kwargs = {"lr": lr0, "betas": (0.9, 0.999), "eps": 1e-7}
    try:
        opt = torch.optim.Adam(field.parameters(), fused=True, **opt_kwargs)
    except (RuntimeError, TypeError):
        opt = torch.optim.Adam(field.parameters(), **opt_kwargs)
    gen = torch.Generator().manual_seed(args.seed + 1)
    rays = prep.train
    lens = rays["counts"][rays["counts"] > 0]
    offs = rays["offsets"][rays["counts"] > 0]
    n_pix = int(lens.shape[0]) * args.rays_per_image

    holdout_idx = None
    if prep.holdout is not None and prep.holdout["n"] > 0:
        hg = torch.Generator().manual_seed(args.seed ^ 0x5EED)
        per_view = -(-4096 // int(prep.holdout["counts"].shape[0]))
        parts = []
        for c, off in zip(prep.holdout["counts"].tolist(), prep.holdout["offsets"].tolist()):
            if c > 0:
                parts.append(off + torch.randint(c, (min(per_view, c),), generator=hg))
        holdout_idx = torch.cat(parts)
        holdout_gen_seed = args.seed ^ 0x5EED

    curve = None
    if truth is not None:
        u, values = truth_points(truth, aabb)
        curve = (torch.from_numpy(u), values)

    def curve_nrmse():
        est = field_values(torch, field, curve[0]).numpy() * prep.value_scale
        return nrmse(est, curve[1])

    losses, nrmse_history, holdout_history = [], [], []
    train_time = 0.0
    train_cpu = 0.0
    cpu_start = time.process_time()
    samples = 0
    stop_reason = "max-iterations"
    it = 0
    while it < args.max_iterations:
        t0, c0 = time.perf_counter(), time.process_time()
        for g in opt.param_groups:
            g["lr"] = lr0 * (lr1 / lr0) ** (it / decay)
        idx = (
            offs[:, None]
            + (torch.rand(lens.shape[0], args.rays_per_image, generator=gen) * lens[:, None]).long()
        )
        idx = torch.minimum(idx, (offs + lens - 1)[:, None]).reshape(-1)
        opt.zero_grad(set_to_none=True)
        loss = render_loss(torch, field, rays, idx, args, scale, gen, n_pix, True)
        opt.step()
        samples += n_pix * (args.coarse_samples + args.fine_samples)
        if not math.isfinite(loss):
            raise RuntimeError(f"the loss became {loss} at iteration {it}")
        losses.append(loss)
        it += 1
        if holdout_idx is not None and it % 100 == 0:
            hgen = torch.Generator().manual_seed(holdout_gen_seed)
            h = render_loss(
                torch, field, prep.holdout, holdout_idx, args, scale, hgen, holdout_idx.shape[0], False
            )
            holdout_history.append([it, h])
        train_time += time.perf_counter() - t0
        train_cpu += time.process_time() - c0
        if curve is not None and args.eval_every > 0 and it % args.eval_every == 0:
            nrmse_history.append({"iteration": it, "train_time_s": train_time, "nrmse": curve_nrmse()})
            if not args.quiet:
                print(
                    f"iteration {it}: loss {loss:.4e}, NRMSE {nrmse_history[-1]['nrmse']:.4f}, "
                    f"{train_time:.1f} s training ({1e3 * train_time / it:.0f} ms/iteration)",
                    file=sys.stderr,
                )
        if converged(losses):
            stop_reason = "converged"
            break
        if args.time_budget is not None and train_time >= args.time_budget:
            stop_reason = "time-budget"
            break
    cpu_s = time.process_time() - cpu_start

    final_nrmse = final_ssim = None
    if truth is not None:
        if not nrmse_history or nrmse_history[-1]["iteration"] != it:
            nrmse_history.append({"iteration": it, "train_time_s": train_time, "nrmse": curve_nrmse()})
        u_all, v_all = truth_points(truth, aabb, stride=1)
        est = field_values(torch, field, torch.from_numpy(u_all)).numpy() * prep.value_scale
        final_nrmse = nrmse(est, v_all)
        rng = float(v_all.max() - v_all.min())
        final_ssim = ssim_global(est, v_all, rng) if rng > 0 else None

    done = max(it, 1)
    return {
        "method": METHOD,
        "preset": args.preset,
        "version": SCRIPT_VERSION,
        "torch_version": torch.__version__,
        "threads": torch.get_num_threads(),
        "num_params": sum(p.numel() for p in field.parameters()),
        "image_scale": prep.image_scale,
        "value_scale": prep.value_scale,
        "mean_level": prep.mean_level,
        "rays_kept": prep.train["n"],
        "rays_on_box": prep.train["n"],
        "prepare_s": settings["prepare_s"],
        "cpu_s": cpu_s,
        "train_cpu_s": train_cpu,
        "seconds_per_iteration": train_time / done,
        "cpu_seconds_per_iteration": train_cpu / done,
        "train": {
            "stop_reason": stop_reason,
            "iterations": it,
            "final_loss": losses[-1] if losses else float("nan"),
            "smoothed_loss": running_mean(losses, 200),
            "train_time_s": train_time,
            "seconds_per_iteration": train_time / done,
            "samples_per_second": samples / train_time if train_time > 0 else 0.0,
        },
        "final_nrmse": final_nrmse,
        "final_ssim_global": final_ssim,
        "nrmse_history": nrmse_history,
        "loss_history": losses,
        "holdout_loss_history": holdout_history,
        "config": settings,
    }


def write_json_atomic(path, value):
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".json", dir=folder)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(value, f, indent=1)
            f.write("\n")
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


# ----------------------------------------------------------------------------------------------
# Self-test: the conventions that the comparison depends on


def self_test(torch, scene_dir):
    failures = []

    def check(name, ok, detail):
        print(f"{'ok  ' if ok else 'FAIL'} {name}: {detail}")
        if not ok:
            failures.append(name)

    gen = torch.Generator().manual_seed(3)
    # (a) A constant field renders to value x normalised chord length, with feature sampling.
    near = torch.rand(256, generator=gen) * 30.0 + 300.0
    far = near + torch.rand(256, generator=gen) * 40.0 + 0.1
    o = torch.rand(256, 3, generator=gen)
    d = torch.rand(256, 3, generator=gen) * 1e-3
    const = lambda u: torch.full(u.shape[:-1], 0.7)  # noqa: E731
    s, w = sample_ray_batch(torch, const, o, d, near, far, 64, 64, 1.0 / 40.0, gen)
    pix = (w * 0.7).sum(-1)
    err = float(((pix - 0.7 * (far - near) / 40.0).abs() / (0.7 * (far - near) / 40.0)).max())
    check("constant field renders to value x chord / L", err < 1e-4, f"max relative error {err:.2e}")
    on_chord = (s >= near[:, None] - 1e-3).all() and (s <= far[:, None] + 1e-3).all()
    check(
        "merged samples sorted and on [near, far]",
        bool((s[:, 1:] >= s[:, :-1]).all() and on_chord),
        f"{s.shape[1]} samples per ray",
    )
    # Without the end pieces only [s_1, s_N] is covered (render.rs test).
    s5 = torch.tensor([[1.3, 1.9, 2.2, 3.7, 4.1]])
    w5 = quadrature_weights(torch, s5, torch.tensor([1.0]), torch.tensor([4.5]), 1.0)
    w5o = quadrature_weights(torch, s5, torch.tensor([1.0]), torch.tensor([4.5]), 1.0, close_ends=False)
    check(
        "trapezoid weights (render.rs known answer)",
        abs(float((w5 * 2).sum()) - 7.0) < 1e-5 and abs(float((w5o * 2).sum()) - 5.6) < 1e-5,
        f"{float((w5 * 2).sum()):.5f} (7), {float((w5o * 2).sum()):.5f} (5.6)",
    )
    # Feature samples follow |dE/ds| (sampling.rs test): a step at s = 3.
    sc = torch.arange(11, dtype=torch.float32)[None] * 0.5
    ec = (sc > 3.1).float()
    sf = feature_samples(torch, sc, ec, 200, gen)
    inside = int(((sf >= 3.0) & (sf <= 3.5)).sum())
    flat = feature_samples(torch, sc, torch.full_like(sc, 0.3), 200, gen)
    check(
        "feature samples follow the step",
        inside >= 195 and int((flat < 2.5).sum()) == 100,
        f"{inside} of 200 in the step's interval; flat: {int((flat < 2.5).sum())} of 200 in the first half",
    )
    # Encoding = Eq. 5.2 on tau = 2u - 1 (encoding.rs test).
    field = build_field(torch, 8, 256, 8, 0)
    u = torch.tensor([[0.1, 0.77, 0.999], [0.0, 0.5, 1.0]])
    g = field.encode(u).double()
    tau = (2 * u - 1).double()
    ref = []
    for r in range(2):
        row = []
        for c in range(3):
            row.append(float(tau[r, c]))
            for k in range(8):
                row += [math.sin(2**k * math.pi * tau[r, c]), math.cos(2**k * math.pi * tau[r, c])]
        ref.append(row)
    eerr = float((g - torch.tensor(ref, dtype=torch.float64)).abs().max())
    check("positional encoding (Eq. 5.2, tau = 2u - 1)", eerr < 2e-6, f"max error {eerr:.1e}")
    n = sum(p.numel() for p in field.parameters())
    check("parameter count (mlp.rs: 487 169)", n == 487_169, str(n))
    start_uniform(torch, field, 0.37)
    vals = field_values(torch, field, torch.rand(4096, 3, generator=gen))
    check(
        "uniform start sits near the level",
        abs(float(vals.mean()) - 0.37) < 0.1,
        f"mean {float(vals.mean()):.3f}",
    )

    # Distorted camera: every pixel's ray, re-projected through the OpenCV model, lands on its
    # pixel centre (OpenCV convention: integer coordinates).
    dist = {"k1": -0.2, "k2": 0.05, "k3": 0.0, "p1": 1e-3, "p2": -5e-4, "k4": 0.01, "k5": 0.0, "k6": 0.0}
    cam = {
        "w": 40,
        "h": 30,
        "fx": 50.0,
        "fy": 52.0,
        "cx": 19.3,
        "cy": 14.6,
        "skew": 0.2,
        "dist": dist,
        "R": np.eye(3),
        "t": np.array([0.0, 0.0, -10.0]),
        "name": "self-test camera",
    }
    _, du, _, _, px = pixel_rays(cam, np.array([-100.0, -100.0, -1.0]), np.array([100.0, 100.0, 1.0]))
    p = du.astype(np.float64) * np.array([200.0, 200.0, 2.0])  # world = camera directions (R = I)
    xd, yd, _ = distort(p[:, 0] / p[:, 2], p[:, 1] / p[:, 2], dist)
    pu = cam["fx"] * xd + cam["skew"] * yd + cam["cx"]
    pv = cam["fy"] * yd + cam["cy"]
    perr = float(np.max(np.hypot(pu - px % 40, pv - px // 40)))
    check(
        "distorted rays re-project onto their pixel centres",
        len(px) == 1200 and perr < 1e-3,
        f"{len(px)} rays, max error {perr:.1e} px (float32 directions)",
    )

    if scene_dir:
        # Camera and box conventions: rendering the truth through this script's rays and
        # quadrature must reproduce the measured pixels (trilinear truth, cell-centred).
        scene = load_scene(scene_dir)
        prep = Prepared(torch, scene)
        truth = scene["truth"]
        if truth is None:
            print(f"{scene['file']}: no truth; skipping the render check")
        else:
            vol = torch.from_numpy(truth)[None, None] / prep.value_scale

            def truth_field(uu):
                grid = (2.0 * uu - 1.0).reshape(1, 1, 1, -1, 3)
                v = torch.nn.functional.grid_sample(
                    vol, grid, mode="bilinear", padding_mode="border", align_corners=False
                )
                return v.reshape(uu.shape[:-1])

            rays = prep.train
            ci = torch.randperm(rays["n"], generator=gen)[:4096]
            s, w = sample_ray_batch(
                torch,
                truth_field,
                rays["o"][ci],
                rays["d"][ci],
                rays["near"][ci],
                rays["far"][ci],
                256,
                0,
                1.0 / prep.length,
                gen,
            )
            pix = (w * truth_field(points(rays["o"][ci], rays["d"][ci], s))).sum(-1)
            t = rays["target"][ci]
            rel = float(((pix - t) ** 2).sum().sqrt() / (t**2).sum().sqrt())
            check(
                "rendered truth reproduces the images",
                rel < 0.05,
                f"relative RMS difference {rel:.4f} over 4096 random pixels (image formation supersamples)",
            )
            print(
                f"scene: {len(scene['views'])} views, {rays['n']} rays on the box, image_scale {prep.image_scale:g}, "
                f"value_scale {prep.value_scale:.6g}, mean level {prep.mean_level:.6g}"
            )
    print("self-test", "FAILED: " + ", ".join(failures) if failures else "passed")
    return 1 if failures else 0


# ----------------------------------------------------------------------------------------------


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", nargs="?", help="scene folder (transforms.json, images, truth)")
    ap.add_argument("--out", help="report JSON to write (refused if it exists, unless --force)")
    ap.add_argument("--force", action="store_true", help="overwrite an existing --out")
    ap.add_argument(
        "--preset",
        default="ch7",
        choices=sorted(PRESETS),
        help="sample counts of `fluidnerf reconstruct --preset` (faithful 128/128, ch7 64/64); default ch7",
    )
    ap.add_argument("--rays-per-image", type=int, default=1024, help="N_pix/img (default 1024)")
    ap.add_argument("--coarse-samples", type=int, help="N_c (default: the preset's)")
    ap.add_argument(
        "--fine-samples", type=int, help="N_f, 0 disables the coarse pass (default: the preset's)"
    )
    ap.add_argument("--time-budget", type=float, help="stop after this many seconds of training")
    ap.add_argument("--max-iterations", type=int, default=25_000, help="iteration cap (default 25 000)")
    ap.add_argument(
        "--eval-every", type=int, default=100, help="NRMSE every N iterations (0: only at the end)"
    )
    ap.add_argument("--threads", type=int, default=2, help="torch.set_num_threads (default 2)")
    ap.add_argument("--seed", type=int, default=0, help="seed of initialisation and sampling (default 0)")
    ap.add_argument(
        "--chunk-rays",
        type=int,
        default=1024,
        help="rays per forward/backward chunk, gradients accumulated (default 1024)",
    )
    ap.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    ap.add_argument(
        "--self-test", action="store_true", help="check the conventions (with SCENE: against its truth)"
    )
    args = ap.parse_args()

    try:
        import torch
    except ImportError:
        print("pytorch unavailable: `import torch` failed", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    if args.self_test:
        return self_test(torch, args.scene)
    if not args.scene or not args.out:
        ap.error("SCENE and --out are required (or --self-test)")
    if os.path.exists(args.out) and not args.force:
        print(f"{args.out} exists; use --force to overwrite it", file=sys.stderr)
        return 1
    nc, nf = PRESETS[args.preset]
    args.coarse_samples = nc if args.coarse_samples is None else args.coarse_samples
    args.fine_samples = nf if args.fine_samples is None else args.fine_samples
    if args.coarse_samples < 2 or args.fine_samples < 0 or args.rays_per_image < 1 or args.chunk_rays < 1:
        ap.error("need --coarse-samples >= 2, --fine-samples >= 0, --rays-per-image >= 1, --chunk-rays >= 1")

    t0 = time.perf_counter()
    try:
        scene = load_scene(args.scene)
        prep = Prepared(torch, scene)
    except SceneError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    prepare_s = time.perf_counter() - t0
    torch.manual_seed(args.seed)
    field = build_field(torch, 8, 256, 8, args.seed)
    if prep.mean_level > 0 and math.isfinite(prep.mean_level):
        start_uniform(torch, field, prep.mean_level)
    settings = {
        "scene": os.path.abspath(args.scene),
        "seed": args.seed,
        "version": SCRIPT_VERSION,
        "preset": args.preset,
        "depth": 8,
        "width": 256,
        "space_freqs": 8,
        "rays_per_image": args.rays_per_image,
        "coarse_samples": args.coarse_samples,
        "fine_samples": args.fine_samples,
        "close_ends": True,
        "learning_rate": [5e-4, 5e-5, 25_000],
        "adam": {"beta1": 0.9, "beta2": 0.999, "eps": 1e-7},
        "max_iterations": args.max_iterations,
        "time_budget_s": args.time_budget,
        "eval_every": args.eval_every,
        "chunk_rays": args.chunk_rays,
        "threads": args.threads,
        "prepare_s": prepare_s,
    }
    report = train(torch, field, prep, scene["truth"], scene["aabb"], args, settings)
    write_json_atomic(args.out, report)
    tr = report["train"]
    print(
        f"{METHOD}: {tr['iterations']} iterations ({tr['stop_reason']}) in {tr['train_time_s']:.1f} s "
        f"({1e3 * report['seconds_per_iteration']:.1f} ms/iteration, {tr['samples_per_second'] / 1e6:.2f} M samples/s, "
        f"{1e3 * report['cpu_seconds_per_iteration']:.1f} CPU ms/iteration), loss {tr['smoothed_loss']:.3e}"
    )
    if report["final_nrmse"] is not None:
        print(f"volume NRMSE {report['final_nrmse']:.4f}, global SSIM {report['final_ssim_global']:.4f}")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
