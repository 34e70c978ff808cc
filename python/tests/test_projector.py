"""The classical projectors and the renderer on NumPy volumes, against an independent NumPy
ray-marching reference and the analytic projection of a Gaussian blob; the exact adjoint;
the metrics' known answers."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fluidnerf
from conftest import look_at, ring, ticks_while

BOX = np.array([[-10.0, -10.0, -10.0], [10.0, 10.0, 10.0]])
CENTRE = np.array([1.0, -0.5, 0.5])
SIGMA = 2.5
N = 32  # voxels per side


def blob_volume() -> np.ndarray:
    """The blob exp(−|p − c|² / 2σ²) sampled at the cell centres, (nz, ny, nx)."""
    axis = BOX[0, 0] + (np.arange(N) + 0.5) * (BOX[1, 0] - BOX[0, 0]) / N
    z, y, x = np.meshgrid(axis, axis, axis, indexing="ij")
    r2 = (x - CENTRE[0]) ** 2 + (y - CENTRE[1]) ** 2 + (z - CENTRE[2]) ** 2
    return np.exp(-r2 / (2 * SIGMA**2)).astype(np.float32)


def pixel_rays(K: np.ndarray, pose: np.ndarray, size: int):
    """Origins and unit directions (world) of the rays through every pixel centre (OpenCV: pixel
    (col, row) at image coordinates (col, row)), row-major."""
    rows, cols = np.meshgrid(np.arange(size), np.arange(size), indexing="ij")
    d_cam = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones_like(cols, float)], -1)
    d = d_cam.reshape(-1, 3) @ pose[:3, :3].T
    return pose[:3, 3], d / np.linalg.norm(d, axis=1, keepdims=True)


def trilinear(vol: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Cell-centred trilinear interpolation of vol (nz, ny, nx) filling BOX; zero outside."""
    spacing = (BOX[1] - BOX[0]) / N
    g = (p - BOX[0]) / spacing - 0.5  # continuous voxel index (x, y, z)
    i0 = np.floor(g).astype(int)
    f = g - i0
    out = np.zeros(len(p))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                ix, iy, iz = i0[:, 0] + dx, i0[:, 1] + dy, i0[:, 2] + dz
                ok = (ix >= 0) & (ix < N) & (iy >= 0) & (iy < N) & (iz >= 0) & (iz < N)
                w = (
                    (f[:, 0] if dx else 1 - f[:, 0])
                    * (f[:, 1] if dy else 1 - f[:, 1])
                    * (f[:, 2] if dz else 1 - f[:, 2])
                )
                out[ok] += w[ok] * vol[iz[ok], iy[ok], ix[ok]]
    return out


def march(vol: np.ndarray, K: np.ndarray, pose: np.ndarray, size: int, step: float = 0.05) -> np.ndarray:
    """∫E ds along every pixel ray through the box, midpoint rule with a fine step."""
    o, d = pixel_rays(K, pose, size)
    dist = np.linalg.norm(o)
    s = np.arange(dist - 20.0, dist + 20.0, step) + step / 2
    image = np.zeros(len(d))
    for chunk in np.array_split(np.arange(len(d)), 8):
        p = o + d[chunk, None, :] * s[None, :, None]
        image[chunk] = trilinear(vol, p.reshape(-1, 3)).reshape(len(chunk), -1).sum(1) * step
    return image.reshape(size, size)


def analytic(K: np.ndarray, pose: np.ndarray, size: int) -> np.ndarray:
    """The blob's exact line integral: σ√(2π) exp(−d² / 2σ²), d the ray's distance from c."""
    o, d = pixel_rays(K, pose, size)
    v = CENTRE - o
    dist2 = (v**2).sum() - (d @ v) ** 2
    return (SIGMA * np.sqrt(2 * np.pi) * np.exp(-dist2 / (2 * SIGMA**2))).reshape(size, size)


@pytest.fixture(scope="module")
def scene():
    n, size = 4, 16
    K, poses = ring(n, size=size)
    return fluidnerf.scene_from_arrays(K, poses, np.zeros((n, size, size), np.float32), BOX), K, poses, size


def test_forward_projection_matches_a_numpy_ray_marcher_and_the_analytic_blob(scene):
    s, K, poses, size = scene
    vol = blob_volume()
    ray = fluidnerf.forward_project(s, vol, "ray")
    splat = fluidnerf.forward_project(s, vol, {"kind": "splat", "splat_subdivisions": 2})
    footprint = fluidnerf.forward_project(s, vol, "footprint")
    chosen = fluidnerf.forward_project(s, vol)  # the voxel methods' automatic choice
    rendered = fluidnerf.render(s, vol)
    assert ray.shape == (4, size, size) and ray.dtype == np.float32
    for v in range(len(poses)):
        ref = march(vol, K[v], poses[v], size)
        peak = ref.max()
        # The independent reference itself is close to the closed form.
        assert np.abs(ref - analytic(K[v], poses[v], size)).max() < 0.015 * peak
        assert np.abs(ray[v] - ref).max() < 0.002 * peak
        assert np.abs(rendered[v] - ref).max() < 0.001 * peak
        # The splat spreads each voxel's footprint bilinearly over pixels (a blurrier model of
        # the same projection): pixels within 15 % of the peak, the total within 1 %.
        assert np.abs(splat[v] - ref).max() < 0.15 * peak
        assert splat[v].sum() == pytest.approx(ref.sum(), rel=0.01)
        # The separable footprint: within 6 % of the peak, the total within 1 %.
        assert np.abs(footprint[v] - ref).max() < 0.06 * peak
        assert footprint[v].sum() == pytest.approx(ref.sum(), rel=0.01)
        assert np.abs(chosen[v] - ref).max() < 0.15 * peak


def test_back_projection_is_the_exact_adjoint(scene):
    s, *_ = scene
    rng = np.random.default_rng(1)
    x = rng.uniform(0, 1, (N, N, N)).astype(np.float32)
    y = rng.uniform(0, 1, (4, 16, 16)).astype(np.float32)
    for projector in ("footprint", "splat", "ray"):
        ax = fluidnerf.forward_project(s, x, projector)
        aty = fluidnerf.back_project(s, y, (N, N, N), projector)
        assert aty.shape == (N, N, N)
        lhs, rhs = float(np.vdot(ax.astype(np.float64), y)), float(np.vdot(x.astype(np.float64), aty))
        assert lhs == pytest.approx(rhs, rel=1e-4), projector
    with pytest.raises(fluidnerf.FluidNerfError, match=r"images: expected 4 images"):
        fluidnerf.back_project(s, y[:3], (N, N, N))
    with pytest.raises(fluidnerf.FluidNerfError, match="projector: unknown field `kinds`"):
        fluidnerf.forward_project(s, x, {"kinds": "ray"})
    with pytest.raises(fluidnerf.FluidNerfError, match="volume: voxel 0"):
        fluidnerf.forward_project(s, np.full((2, 2, 2), np.nan, np.float32))


def test_the_extension_reads_a_fortran_ordered_volume_by_its_indices(scene):
    """The extension copied any contiguous array's memory as C order: a Fortran-ordered
    volume given to it directly (its typed stub allows that) was read transposed."""
    from fluidnerf import _fluidnerf as ext

    s, *_ = scene
    vol = np.random.default_rng(2).uniform(0, 1, (5, 6, 7)).astype(np.float32)
    np.testing.assert_array_equal(
        ext.forward_project(s, np.asfortranarray(vol), "{}"), ext.forward_project(s, vol, "{}")
    )
    np.testing.assert_array_equal(ext.render(s, np.asfortranarray(vol), None, 1), ext.render(s, vol, None, 1))


def test_a_ring_exactly_about_y_projects_and_back_projects_on_the_volumes_axes():
    """Cameras in the plane y = 0 see the grid's y rows as vertical lines: the footprint
    projector then works on renamed axes, where its rows share footprints. Images and the
    adjoint are as for any ring: the NumPy ray marcher, the closed form and <Ax, y> = <x, Aᵀy>."""
    n, size = 4, 16
    K, _ = ring(n, size=size)
    angles = np.arange(n) * 2 * np.pi / n + 0.4
    poses = np.stack(
        [look_at([60.0 * np.cos(a), 0.0, 60.0 * np.sin(a)], [0, 0, 0], [0, 1, 0]) for a in angles]
    )
    s = fluidnerf.scene_from_arrays(K, poses, np.zeros((n, size, size), np.float32), BOX)
    vol = blob_volume()
    footprint = fluidnerf.forward_project(s, vol, "footprint")
    for v in range(n):
        ref = march(vol, K[v], poses[v], size)
        peak = ref.max()
        assert np.abs(footprint[v] - ref).max() < 0.06 * peak
        assert footprint[v].sum() == pytest.approx(ref.sum(), rel=0.01)
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 1, (N, N, N)).astype(np.float32)
    y = rng.uniform(0, 1, (n, size, size)).astype(np.float32)
    ax = fluidnerf.forward_project(s, x, "footprint")
    aty = fluidnerf.back_project(s, y, (N, N, N), "footprint")
    lhs, rhs = float(np.vdot(ax.astype(np.float64), y)), float(np.vdot(x.astype(np.float64), aty))
    assert lhs == pytest.approx(rhs, rel=1e-4)


def test_metrics_give_their_known_answers():
    t = blob_volume()
    assert fluidnerf.nrmse(2 * t, t) == pytest.approx(1.0, rel=1e-6)
    assert fluidnerf.nrmse(t, t) == 0.0
    r = float(t.max() - t.min())
    assert fluidnerf.psnr(t + 0.01, t) == pytest.approx(10 * np.log10(r**2 / 1e-4), rel=1e-4)
    assert fluidnerf.ssim(t, t) == pytest.approx(1.0)
    assert fluidnerf.ssim(t[0], t[0], window="gaussian") == pytest.approx(1.0)
    # Global SSIM against its formula.
    e = t * 0.8 + 0.05
    a, b = e.astype(np.float64).ravel(), t.astype(np.float64).ravel()
    c1, c2 = (0.01 * r) ** 2, (0.03 * r) ** 2
    cov = ((a - a.mean()) * (b - b.mean())).mean()
    want = (
        (2 * a.mean() * b.mean() + c1)
        * (2 * cov + c2)
        / ((a.mean() ** 2 + b.mean() ** 2 + c1) * (a.var() + b.var() + c2))
    )
    assert fluidnerf.ssim(e, t, window="global") == pytest.approx(want, rel=1e-9)
    with pytest.raises(fluidnerf.FluidNerfError, match="differ in shape"):
        fluidnerf.nrmse(t, t[0])


def test_ssim_releases_the_gil_while_it_computes():
    """The SSIM of a large volume takes seconds, during which every other Python thread
    stopped."""
    rng = np.random.default_rng(0)
    truth = rng.random((128, 128, 128), dtype=np.float32)
    estimate = truth + np.float32(0.01)
    during, elapsed = ticks_while(lambda: fluidnerf.ssim(estimate, truth, window="gaussian"))
    # A thread sleeping 1 ms at a time ticks about once per 1 ms the SSIM leaves it free. Ten
    # ticks need ten free milliseconds at least; a call that holds the GIL leaves the thread one
    # tick at most, however long it takes.
    assert during >= 10, (during, elapsed)


def test_an_ssim_window_wider_than_the_arrays_names_their_shape_as_given():
    """The message gave the sides x first: (1, 30, 30) was "array of dims [30, 30, 1]", and
    named neither the arguments nor the way out."""
    flat = np.ones((1, 30, 30), np.float32)
    with pytest.raises(
        fluidnerf.FluidNerfError,
        match=r"^estimate and truth: shape \(1, 30, 30\) has a side shorter than the 7-wide SSIM window of "
        r'window="uniform"; .*window="global"',
    ):
        fluidnerf.ssim(flat, flat)
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"shape \(5, 40\) has a side shorter than the 11-wide"
    ):
        fluidnerf.ssim(np.ones((5, 40)), np.ones((5, 40)), window="gaussian")
    assert fluidnerf.ssim(flat, flat, window="global") == pytest.approx(1.0)


def test_render_refuses_steps_and_supersampling_it_would_never_finish(scene):
    """A step of 1e-300 or 10⁵ rays per pixel axis held the interpreter for good (the renderer
    takes no Ctrl-C); a float or negative ray count was truncated or raised a nameless error."""
    s, *_ = scene
    vol = np.ones((4, 4, 4), np.float32)
    with pytest.raises(fluidnerf.FluidNerfError, match=r"step: 1e-300 would take more than 1048576 samples"):
        fluidnerf.render(s, vol, step=1e-300)
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"step: must be a positive number of world units, got -1"
    ):
        fluidnerf.render(s, vol, step=-1.0)
    with pytest.raises(fluidnerf.FluidNerfError, match=r"supersample: .* between 1 and 64, got 100000"):
        fluidnerf.render(s, vol, supersample=100_000)
    for bad in (0, -1):
        with pytest.raises(fluidnerf.FluidNerfError, match=rf"supersample: must be at least 1, got {bad}"):
            fluidnerf.render(s, vol, supersample=bad)
    with pytest.raises(TypeError, match="supersample: expected an integer, got 2.5"):
        fluidnerf.render(s, vol, supersample=2.5)
    # Beyond 64 bits it raised pyo3's bare "OverflowError: int too big to convert".
    with pytest.raises(fluidnerf.FluidNerfError, match=r"supersample: 2361183241434822606848 is more than"):
        fluidnerf.render(s, vol, supersample=2**71)
    assert fluidnerf.render(s, vol, step=0.5, supersample=np.int64(2)).shape == (4, 16, 16)


def test_an_integer_beyond_floats_is_refused_naming_the_argument(scene, tmp_path):
    """An integer too large for a float (10**400) raised Python's bare "OverflowError: int too
    large to convert to float" naming no argument, and a string step or data range pyo3's
    "argument 'step': must be real number, not str"."""
    s, K, poses, *_ = scene
    vol = np.ones((4, 4, 4), np.float32)
    huge = 10**400
    beyond = "an integer of 401 digits is beyond the range of floating-point numbers"
    with pytest.raises(fluidnerf.FluidNerfError, match=f"step: {beyond}"):
        fluidnerf.render(s, vol, step=huge)
    with pytest.raises(TypeError, match="step: expected a number, got '1'"):
        fluidnerf.render(s, vol, step="1")
    for metric in (fluidnerf.psnr, fluidnerf.ssim):
        with pytest.raises(fluidnerf.FluidNerfError, match=f"data_range: {beyond}"):
            metric(blob_volume(), blob_volume(), huge)
        with pytest.raises(TypeError, match="data_range: expected a number, got '1'"):
            metric(blob_volume(), blob_volume(), "1")
    with pytest.raises(fluidnerf.FluidNerfError, match=f"intensity_scale: {beyond}"):
        fluidnerf.scene_from_arrays(
            K, poses, np.ones((len(K), 16, 16), np.float32), BOX, intensity_scale=huge
        )
    np.save(tmp_path / "volume.npy", vol)
    run = fluidnerf.open_run(tmp_path, aabb=BOX)
    with pytest.raises(fluidnerf.FluidNerfError, match=f"time: {beyond}"):
        run.field(np.zeros((1, 3)), time=huge)


def test_a_bool_where_a_number_is_expected_is_refused_naming_the_argument(scene, tmp_path):
    """step=True rendered with a step of one world unit, data_range=True scored against a peak
    of 1, and intensity_scale=True built a scene of scale 1: a bool was read as 1.0."""
    s, K, poses, *_ = scene
    vol = np.ones((4, 4, 4), np.float32)
    for flag in (True, np.bool_(False)):
        with pytest.raises(TypeError, match=f"step: expected a number, got {flag!r}"):
            fluidnerf.render(s, vol, step=flag)
        for metric in (fluidnerf.psnr, fluidnerf.ssim):
            with pytest.raises(TypeError, match=f"data_range: expected a number, got {flag!r}"):
                metric(blob_volume(), blob_volume(), flag)
        with pytest.raises(TypeError, match=f"intensity_scale: expected a number, got {flag!r}"):
            fluidnerf.scene_from_arrays(
                K, poses, np.ones((len(K), 16, 16), np.float32), BOX, intensity_scale=flag
            )
    np.save(tmp_path / "volume.npy", vol)
    run = fluidnerf.open_run(tmp_path, aabb=BOX)
    with pytest.raises(TypeError, match="time: expected a number, got True"):
        run.field(np.zeros((1, 3)), time=True)


def test_a_volume_whose_images_overflow_floats_is_refused(scene):
    """forward_project and render of a volume of values near the largest float32 returned images
    of infinities and NaN without a word."""
    s, *_ = scene
    huge = np.full((4, 4, 4), 3e38, np.float32)
    for project in (fluidnerf.forward_project, fluidnerf.render):
        with pytest.raises(
            fluidnerf.FluidNerfError, match="volume: values up to 3.000e38 .* beyond the largest 32-bit"
        ):
            project(s, huge)
        assert np.isfinite(project(s, huge / 1e34)).all()


def test_images_whose_back_projection_overflows_floats_are_refused(scene):
    """back_project of images near the largest float32 returned a volume of NaN without a word."""
    s, K, _, size = scene
    huge = np.full((len(K), size, size), 3e38, np.float32)
    with pytest.raises(
        fluidnerf.FluidNerfError, match="images: pixels up to 3.000e38, .* beyond the largest 32-bit"
    ):
        fluidnerf.back_project(s, huge, (4, 4, 4))
    assert np.isfinite(fluidnerf.back_project(s, huge / 1e30, (4, 4, 4))).all()


def test_a_data_range_wider_than_float32_values_is_refused():
    """data_range=1e300 made the PSNR infinite and the SSIM NaN without a word: its square
    overflowed. A range no two float32 values differ by is refused; the widest one still
    scores."""
    t = blob_volume()
    widest = 2.0 * float(np.finfo(np.float32).max)
    for metric in (fluidnerf.psnr, fluidnerf.ssim, lambda a, b, r: fluidnerf.ssim(a, b, r, "global")):
        with pytest.raises(
            fluidnerf.FluidNerfError, match="data_range: .* is more than any two float32 values differ by"
        ):
            metric(t, t * 0.9, 1e300)
        assert np.isfinite(metric(t, t * 0.9, widest))


def test_a_data_range_too_small_for_its_square_gives_a_finite_psnr_and_is_refused_by_ssim():
    """data_range=1e-300 made the PSNR -inf (its square underflowed) and the global SSIM NaN
    without a word. The PSNR of such a range is finite (20 log10 R - 10 log10 MSE) and given;
    SSIM's constants (K R)^2 vanish, so SSIM refuses it. NRMSE takes no range."""
    t = np.zeros((12, 12), np.float32)
    e = t.copy()
    e[0, 0] = 2.0
    mse = 4.0 / 144
    for r in (1e-300, 1e-160, 1.0, 1e30):
        assert fluidnerf.psnr(e, t, r) == pytest.approx(20 * np.log10(r) - 10 * np.log10(mse), rel=1e-12)
    for window in ("uniform", "gaussian", "global"):
        with pytest.raises(
            fluidnerf.FluidNerfError, match=r"data_range: 1e-300 is so small that SSIM's constants"
        ):
            fluidnerf.ssim(t, t, 1e-300, window)
        # The smallest difference of two float32 values still scores.
        tiny = float(np.finfo(np.float32).smallest_subnormal)
        assert fluidnerf.ssim(t, t, tiny, window) == pytest.approx(1.0)


def test_back_projection_refuses_images_that_are_not_finite(scene):
    """A NaN or infinite pixel gave a volume of NaN without a word."""
    s, *_ = scene
    y = np.ones((4, 16, 16), np.float32)
    y[2, 5, 7] = np.inf
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"images\[2\]: pixel \(row 5, column 7\) is not finite \(inf\)"
    ):
        fluidnerf.back_project(s, y, (N, N, N))
    y[2, 5, 7] = np.nan
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"images\[2\]: pixel \(row 5, column 7\) is not finite \(NaN\)"
    ):
        fluidnerf.back_project(s, list(y), (N, N, N))


def test_visual_hull_settings_are_refused_by_the_projections(scene):
    """A visual hull given to a projection was accepted and ignored: the images and the volume
    were those without it."""
    s, *_ = scene
    vol = np.ones((N, N, N), np.float32)
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"projector: visual_hull set\(s\) the visual hull .* leave it out"
    ):
        fluidnerf.forward_project(s, vol, {"kind": "footprint", "visual_hull": True})
    with pytest.raises(fluidnerf.FluidNerfError, match=r"projector: hull_threshold, hull_dilation set"):
        fluidnerf.back_project(
            s, np.ones((4, 16, 16), np.float32), (N, N, N), {"hull_threshold": 0.1, "hull_dilation": 3}
        )
    # The other settings still apply.
    assert fluidnerf.forward_project(s, vol, {"kind": "ray", "ray_step": 0.25}).shape == (4, 16, 16)


def test_a_footprint_memory_is_refused_by_the_projections(scene):
    """kept_footprints_mib given to a projection, which makes one pass and keeps no
    footprints, was accepted and set to 0 without a word."""
    s, *_ = scene
    vol = np.ones((N, N, N), np.float32)
    with pytest.raises(fluidnerf.FluidNerfError, match=r"^projector: kept_footprints_mib .* leave it out$"):
        fluidnerf.forward_project(s, vol, {"kind": "footprint", "kept_footprints_mib": 4096})
    with pytest.raises(fluidnerf.FluidNerfError, match=r"^projector: kept_footprints_mib "):
        fluidnerf.back_project(s, np.ones((4, 16, 16), np.float32), (N, N, N), {"kept_footprints_mib": 0})


def test_a_back_projection_beyond_the_memory_is_refused_not_aborted(tmp_path):
    """A shape whose volume the memory could not hold aborted the process ("memory allocation
    of 13500000000 bytes failed"), the interpreter with it. Run in a process limited to 4 GiB
    of address space, it is now refused naming the shape."""
    code = f"""
import resource, sys
sys.path.insert(0, {str(Path(__file__).parent)!r})
import numpy as np
import fluidnerf
from conftest import ring
K, poses = ring(4)
scene = fluidnerf.scene_from_arrays(K, poses, np.ones((4, 16, 16), np.float32), [[-10] * 3, [10] * 3])
resource.setrlimit(resource.RLIMIT_AS, (4 << 30, resource.getrlimit(resource.RLIMIT_AS)[1]))
try:
    fluidnerf.back_project(scene, np.ones((4, 16, 16), np.float32), (1500, 1500, 1500))
except fluidnerf.FluidNerfError as e:
    print(e)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert re.match(
        r"shape: a volume of \(1500, 1500, 1500\) voxels needs (about )?\d+ MiB of memory.*give a smaller shape",
        done.stdout,
    ), done.stdout


def test_back_projection_refuses_a_shape_that_is_not_three_positive_integers(scene):
    """A negative side raised an OverflowError naming nothing, two sides a bare unpacking
    error, and a side of 6.5 was truncated to 6."""
    s, *_ = scene
    y = np.ones((4, 16, 16), np.float32)
    with pytest.raises(fluidnerf.FluidNerfError, match=r"shape\[0\]: must be at least 1, got -1"):
        fluidnerf.back_project(s, y, (-1, N, N))
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"shape: expected the volume's three sides .*\(6, 6\)"
    ):
        fluidnerf.back_project(s, y, (6, 6))
    with pytest.raises(fluidnerf.FluidNerfError, match=r"shape: expected the volume's three sides .* 6"):
        fluidnerf.back_project(s, y, 6)
    with pytest.raises(TypeError, match=r"shape\[2\]: expected an integer, got 6.5"):
        fluidnerf.back_project(s, y, (N, N, 6.5))
    assert fluidnerf.back_project(s, y, np.array([N, N, N])).shape == (N, N, N)


def test_back_projection_refuses_a_shape_of_more_voxels_than_the_projectors_hold(scene):
    """Sides of 2^40 made the footprint projector panic ("internal error (please report):
    chunk_size must not be zero"), and a side of 2^64 raised a bare OverflowError."""
    s, *_ = scene
    y = np.ones((4, 16, 16), np.float32)
    for shape, count in [((2**40,) * 3, 2**120), ((2**16, 2**16, 1), 2**32)]:
        with pytest.raises(
            fluidnerf.FluidNerfError,
            match=rf"shape: .* makes {count} voxels, more than the 4294967295 \(2\^32 - 1\) the projectors hold",
        ):
            fluidnerf.back_project(s, y, shape)
    with pytest.raises(fluidnerf.FluidNerfError, match=r"shape\[0\]: 18446744073709551616 is more than"):
        fluidnerf.back_project(s, y, (2**64, 1, 1))
    # The extension refuses it as well, naming the argument.
    with pytest.raises(fluidnerf.FluidNerfError, match=r"shape: .* more voxels than the 4294967295"):
        fluidnerf._fluidnerf.back_project(s, list(y), (2**40,) * 3)


def test_arrays_that_are_no_real_numbers_are_refused_naming_the_argument(scene):
    """A complex estimate lost its imaginary part (NRMSE 1.0 with only NumPy's warning), and a
    string or a ragged list raised NumPy's ValueError, a scalar for the images Python's "'float'
    object is not iterable": none named the argument."""
    s, *_ = scene
    t = blob_volume()
    for metric in (fluidnerf.nrmse, fluidnerf.psnr, fluidnerf.ssim):
        with pytest.raises(TypeError, match="estimate: expected real numbers, got complex ones"):
            metric(t.astype(np.complex64), t)
        with pytest.raises(TypeError, match=r"truth: expected an array of numbers, got strings \(<U5\)"):
            metric(t, "truth")
    with pytest.raises(TypeError, match="truth: expected an array of numbers: .*inhomogeneous"):
        fluidnerf.nrmse([1.0, 2.0], [[1.0], [2.0, 3.0]])
    y = np.ones((4, 16, 16), np.float32)
    with pytest.raises(
        TypeError, match=r"images: expected an \(N, H, W\) array or a list of \(H, W\) arrays"
    ):
        fluidnerf.back_project(s, 1.0, (N, N, N))
    with pytest.raises(TypeError, match=r"images: expected an \(N, H, W\) array .*got 'abc'"):
        fluidnerf.back_project(s, "abc", (N, N, N))
    with pytest.raises(TypeError, match=r"images\[0\]: expected real numbers of shape \(H, W\), got complex"):
        fluidnerf.back_project(s, y.astype(np.complex64), (N, N, N))
    assert fluidnerf.back_project(s, list(y), (N, N, N)).shape == (N, N, N)
    # A mask passed for numbers would read as zeros and ones.
    with pytest.raises(TypeError, match="truth: expected an array of numbers, got booleans"):
        fluidnerf.nrmse(t, t > 0.5)
    with pytest.raises(TypeError, match=r"images\[0\]: expected an array of numbers.*, got booleans"):
        fluidnerf.back_project(s, y > 0, (N, N, N))


def test_strings_dates_and_durations_are_refused_as_no_numbers(scene):
    """NumPy cast strings of digits, dates and durations to numbers: nrmse("12", "13") gave
    0.077, an array of dates compared as days since 1970, and images of strings were back
    projected, all without a word."""
    s, *_ = scene
    t = blob_volume()
    for given, what in [
        (np.array(["1.5", "2"]), r"strings \(<U3\)"),
        ("12", r"strings \(<U2\)"),
        (np.array([b"1", b"2"]), r"strings \(\|S1\)"),
        (np.array(["1", 2], dtype=object), r"strings \(object\)"),
        (np.array(["2020-01-01", "2020-01-02"], dtype="M8[D]"), r"dates \(datetime64\[D\]\)"),
        (np.array([1, 2], dtype="m8[s]"), r"durations \(timedelta64\[s\]\)"),
    ]:
        with pytest.raises(TypeError, match=f"^estimate: expected an array of numbers, got {what}"):
            fluidnerf.nrmse(given, np.array([1.0, 3.0]))
    with pytest.raises(
        TypeError, match=r"^volume: expected an array of numbers of shape \(nz, ny, nx\), got strings"
    ):
        fluidnerf.forward_project(s, t.astype(str))
    y = np.ones((4, 16, 16), np.float32)
    with pytest.raises(
        TypeError, match=r"^images\[0\]: expected an array of numbers of shape \(H, W\), got strings"
    ):
        fluidnerf.back_project(s, y.astype(str), (N, N, N))


def test_a_masked_array_is_refused_rather_than_its_mask_ignored(scene):
    """np.asarray dropped a masked array's mask: the metrics, projections and scenes used the
    values under it as if they were data."""
    s, *_ = scene
    t = blob_volume()
    masked = np.ma.masked_array(t, mask=t < 0.5 * t.max())
    n = int(masked.mask.sum())
    with pytest.raises(
        fluidnerf.FluidNerfError, match=rf"^estimate: a masked array with {n} masked element\(s\)"
    ):
        fluidnerf.nrmse(masked, t)
    with pytest.raises(fluidnerf.FluidNerfError, match=r"^volume: a masked array .* mask would be ignored"):
        fluidnerf.forward_project(s, masked)
    # A masked array of which nothing is masked is its values.
    assert fluidnerf.nrmse(np.ma.masked_array(t), t) == 0.0


def test_metrics_refuse_values_that_are_not_finite_and_a_zero_truth():
    """A NaN or an infinity in either array made every metric NaN (or inf) without a word, and
    an all-zero truth made the NRMSE NaN."""
    t = blob_volume()
    bad = t.copy()
    bad[1, 2, 3] = np.nan
    flat = np.ravel_multi_index((1, 2, 3), t.shape)
    for metric in (fluidnerf.nrmse, fluidnerf.psnr, fluidnerf.ssim):
        with pytest.raises(
            fluidnerf.FluidNerfError, match=rf"estimate: element {flat} \(flat index, C order\)"
        ):
            metric(bad, t)
        with pytest.raises(
            fluidnerf.FluidNerfError, match=rf"truth: element {flat} .* is not finite \(NaN\)"
        ):
            metric(t, bad)
    with pytest.raises(fluidnerf.FluidNerfError, match="truth: every element is zero"):
        fluidnerf.nrmse(t, np.zeros_like(t))


def test_finite_values_beyond_float32_are_refused_as_such(scene):
    """A float64 value of 1e300 (or a Python integer of 2**200) was cast to a float32 infinity,
    with NumPy's RuntimeWarning, and refused as "not finite (inf)", a value nobody gave."""
    import warnings

    s, *_ = scene
    t = blob_volume().astype(np.float64)
    big = t.copy()
    big[1, 2, 3] = -1e300
    flat = np.ravel_multi_index((1, 2, 3), t.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for metric in (fluidnerf.nrmse, fluidnerf.psnr, fluidnerf.ssim):
            with pytest.raises(
                fluidnerf.FluidNerfError,
                match=rf"estimate: element {flat} \(flat index, C order\), -1e\+300, is beyond the float32 "
                r"values it is computed in \(at most 3.4028235e\+38 in magnitude\)",
            ):
                metric(big, t)
        with pytest.raises(
            fluidnerf.FluidNerfError, match=rf"volume: element {flat} .*, -1e\+300, is beyond"
        ):
            fluidnerf.forward_project(s, big)
        y = np.ones((4, 16, 16))
        y[2, 5, 7] = 1e39
        with pytest.raises(fluidnerf.FluidNerfError, match=r"images\[2\]: element 87 .*, 1e\+39, is beyond"):
            fluidnerf.back_project(s, y, (N, N, N))
        # Python integers beyond float32 (an array of objects) were cast to an infinity and
        # refused as "not finite (inf)", and beyond float64 raised a bare OverflowError.
        for big_int in (2**200, -(2**2000)):
            digits = len(str(abs(big_int)))
            with pytest.raises(
                fluidnerf.FluidNerfError,
                match=rf"^estimate: element 1 \(flat index, C order\), an integer of {digits} digits, is "
                r"beyond the float32 values",
            ):
                fluidnerf.nrmse([1, big_int], [1.0, 2.0])


def test_an_ssim_window_that_is_no_string_is_refused_naming_the_argument():
    """window=7 raised pyo3's "argument 'window': 'int' object cannot be converted to 'PyString'"."""
    t = blob_volume()
    for window in (7, None):
        with pytest.raises(
            TypeError, match=rf"^window: expected a string, got {type(window).__name__} {window}"
        ):
            fluidnerf.ssim(t, t, window=window)


def test_back_projection_refuses_images_that_are_no_stack_of_images_naming_their_shape(scene):
    """One (H, W) image was read row by row, as H images: "expected 4 images (one per frame),
    got 16"; a dict was read by its keys, as images of strings."""
    s, *_ = scene
    y = np.ones((4, 16, 16), np.float32)
    for bad, shape in ((y[0], r"\(16, 16\)"), (y[..., None], r"\(4, 16, 16, 1\)"), (y[0, 0], r"\(16,\)")):
        with pytest.raises(
            fluidnerf.FluidNerfError, match=rf"^images: expected shape \(N, H, W\), got .*{shape}"
        ):
            fluidnerf.back_project(s, bad, (N, N, N))
    with pytest.raises(
        TypeError, match=r"^images: expected an \(N, H, W\) array or a list of \(H, W\) arrays, got dict"
    ):
        fluidnerf.back_project(s, dict(enumerate(y)), (N, N, N))
    assert fluidnerf.back_project(s, list(y), (N, N, N)).shape == (N, N, N)
