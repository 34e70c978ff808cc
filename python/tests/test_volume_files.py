"""Volume files against an independent reader and writer: the ImageJ TIFF stacks `fluidnerf
export --tiff` writes are read by `tifffile` with their values, voxel size and place, and the
stacks `tifffile` writes for ImageJ are read by fluidnerf with theirs."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

tifffile = pytest.importorskip("tifffile")


def imagej_stack(path, volume, voxel, origin):
    """Writes `volume` (nz, ny, nx) as tifffile writes a stack for ImageJ: voxel sizes (x, y, z)
    in mm, the origin in voxels (ImageJ's xorigin, yorigin, zorigin)."""
    metadata = {"axes": "ZYX", "unit": "mm", "spacing": voxel[2]}
    metadata.update(zip(("xorigin", "yorigin", "zorigin"), origin))
    tifffile.imwrite(path, volume, imagej=True, resolution=(1 / voxel[0], 1 / voxel[1]), metadata=metadata)


def run(cli, *args):
    out = subprocess.run([cli, *map(str, args)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out


def test_an_exported_stack_is_the_volume_with_its_calibration(static_scene, cli, tmp_path):
    rng = np.random.default_rng(5)
    volume = rng.random((6, 5, 7), dtype=np.float32)
    np.save(tmp_path / "v.npy", volume)
    run(
        cli,
        "export",
        tmp_path / "v.npy",
        "--scene",
        static_scene.root,
        "-o",
        tmp_path / "out",
        "--tiff",
        "--npy",
    )
    exported = np.load(tmp_path / "out" / "volume.npy")
    lo, hi = np.array(static_scene.aabb[0]), np.array(static_scene.aabb[1])
    with tifffile.TiffFile(tmp_path / "out" / "volume.tif") as tif:
        assert tif.is_imagej
        stack = tif.asarray()
        meta = tif.imagej_metadata
        page = tif.pages[0]
        per_unit = [page.tags[t].value for t in ("XResolution", "YResolution")]
    np.testing.assert_array_equal(stack, exported)
    dims = np.array(exported.shape[::-1])
    spacing = (hi - lo) / dims
    assert meta["images"] == meta["slices"] == dims[2] and meta["unit"] == static_scene.units
    np.testing.assert_allclose([d / n for n, d in per_unit], spacing[:2], rtol=1e-9)
    np.testing.assert_allclose(meta["spacing"], spacing[2], rtol=1e-12)
    # ImageJ's origin counts pixels from the box's corner: pixel i spans [i, i + 1).
    origin = np.array([meta["xorigin"], meta["yorigin"], meta["zorigin"]])
    np.testing.assert_allclose(-origin * spacing, lo, rtol=1e-12, atol=1e-12)
    assert (meta["min"], meta["max"]) == pytest.approx((float(exported.min()), float(exported.max())))


def test_a_stack_written_for_imagej_is_read_with_its_box(cli, tmp_path):
    rng = np.random.default_rng(6)
    volume = rng.random((4, 3, 5), dtype=np.float32)
    imagej_stack(tmp_path / "stack.tif", volume, (0.5, 0.25, 0.75), (4.0, -2.0, 1.0))
    run(cli, "export", tmp_path / "stack.tif", "-o", tmp_path / "out", "--npy")
    np.testing.assert_array_equal(np.load(tmp_path / "out" / "volume.npy"), volume)
    settings = json.loads((tmp_path / "out" / "export.json").read_text())
    np.testing.assert_allclose(settings["aabb"]["min"], [-2.0, 0.5, -0.75])
    np.testing.assert_allclose(settings["aabb"]["max"], [0.5, 1.25, 2.25])


def test_a_stack_without_calibration_needs_the_scene_for_its_box(static_scene, cli, tmp_path):
    volume = np.arange(3 * 4 * 5, dtype=np.uint16).reshape(3, 4, 5)
    tifffile.imwrite(tmp_path / "plain.tif", volume, photometric="minisblack")
    out = subprocess.run(
        [cli, "export", str(tmp_path / "plain.tif"), "-o", str(tmp_path / "a"), "--npy"],
        capture_output=True,
        text=True,
    )
    assert out.returncode != 0 and "plain.tif" in out.stderr and "holds no box" in out.stderr
    run(cli, "export", tmp_path / "plain.tif", "--scene", static_scene.root, "-o", tmp_path / "b", "--npy")
    np.testing.assert_array_equal(np.load(tmp_path / "b" / "volume.npy"), volume.astype(np.float32))


def test_a_scene_is_synthesised_from_a_stack_as_from_the_command_line(cli, tmp_path):
    import fluidnerf

    rng = np.random.default_rng(7)
    volume = rng.random((10, 8, 12), dtype=np.float32)
    imagej_stack(tmp_path / "truth.tif", volume, (2.0, 2.5, 3.0), (6.0, 4.0, 5.0))
    small = {"rig": {"layout": {"count": 4}}, "lens": {"resolution": [16, 16]}}
    phantom = {"kind": "volume", "volume_path": str(tmp_path / "truth.tif")}
    scene = fluidnerf.synth(tmp_path / "py", "demo", phantom=phantom, **small)
    np.testing.assert_allclose(scene.aabb, [[-12.0, -10.0, -15.0], [12.0, 10.0, 15.0]])
    [(_, truth)] = scene.truth()
    np.testing.assert_array_equal(truth, volume)
    # The command line makes the same scene from the same settings.
    settings = tmp_path / "py" / "synth.json"
    run(cli, "synth", "--config", settings, "-o", tmp_path / "cli", "-q")
    for name in ["images/cam000.png", "truth/truth.npy"]:
        assert (tmp_path / "py" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    # The stack's box is its own: another is refused, as is another grid.
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"aabb: the truth volume .*truth\.tif holds its own box"
    ):
        fluidnerf.synth(tmp_path / "a", "demo", phantom=phantom, aabb=[[0, 0, 0], [1, 1, 1]], **small)
    with pytest.raises(fluidnerf.FluidNerfError, match=r"resolution: the truth volume .* on its own grid"):
        fluidnerf.synth(tmp_path / "b", "demo", phantom=phantom, resolution=16, **small)
