"""Scenes: built from arrays, saved, loaded back unchanged; bad arrays refused by name."""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import subprocess
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import fluidnerf
from conftest import ring, ticks_while


def test_a_scene_from_arrays_round_trips_through_a_folder(tmp_path):
    n, size = 6, 16
    K, poses = ring(n, size=size)
    K[2, 0, 0] = 31.5  # per-frame intrinsics
    rng = np.random.default_rng(0)
    images = rng.uniform(0.0, 2.0, (n, size, size)).astype(np.float32)
    aabb = np.array([[-10.0, -8.0, -10.0], [10.0, 8.0, 10.0]])
    times = np.array([0.0, 0.0, 0.0, 0.5, 0.5, 0.5])
    distortion = np.zeros((n, 5))
    distortion[1] = [0.01, -0.002, 0.0005, -0.0003, 0.0001]
    holdout = [False, False, True, False, False, False]
    names = ["a", "b", "c", "a", "b", "c"]
    scene = fluidnerf.scene_from_arrays(
        K,
        poses,
        images,
        aabb,
        times=times,
        distortion=distortion,
        holdout=holdout,
        names=names,
        units="cm",
        intensity_scale=2.5,
    )
    assert scene.root is None and len(scene) == n
    np.testing.assert_array_equal(scene.images(), images)

    scene.save(tmp_path / "s")
    back = fluidnerf.load_scene(tmp_path / "s")
    assert back.root == (tmp_path / "s").absolute()
    k2, p2, d2, sizes = back.camera_arrays()
    np.testing.assert_allclose(k2, K, rtol=0, atol=1e-12)
    np.testing.assert_allclose(p2, poses, rtol=0, atol=1e-12)
    np.testing.assert_allclose(d2[:, :5], distortion, rtol=0, atol=1e-15)
    assert (sizes == [size, size]).all()
    np.testing.assert_array_equal(back.images(), images)  # float32 TIFF: exact
    np.testing.assert_array_equal(back.aabb, aabb)
    assert back.times == list(times) and back.holdout == holdout and back.names == names
    assert back.units == "cm" and back.intensity_scale == 2.5
    with pytest.raises(fluidnerf.FluidNerfError, match="units: the length unit must be named"):
        fluidnerf.scene_from_arrays(K, poses, images, aabb, units=" ")
    # The same file through the transforms.json importer.
    again = fluidnerf.read_transforms(tmp_path / "s" / "transforms.json")
    np.testing.assert_allclose(again.camera_arrays()[1], poses, atol=1e-12)
    with pytest.raises(fluidnerf.FluidNerfError, match="already holds a scene"):
        scene.save(tmp_path / "s")
    # Nor into a folder of another kind, as synth and import refuse: it wrote transforms.json
    # and images/ among a run's files.
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text('{"scene": "elsewhere", "method": {"name": "asart"}}')
    with pytest.raises(fluidnerf.FluidNerfError, match="run: is a reconstruction run folder"):
        scene.save(run, force=True)
    assert sorted(p.name for p in run.iterdir()) == ["config.json"]


def test_saving_a_scene_releases_the_gil_while_it_writes(tmp_path):
    """The images (and truth) of a large scene take a while to write, during which every other
    Python thread stood still."""
    K, poses = ring(8, size=1024, focal=600.0)
    images = np.random.default_rng(0).random((8, 1024, 1024), dtype=np.float32)
    scene = fluidnerf.scene_from_arrays(K, poses, images, [[-10, -10, -10], [10, 10, 10]])
    during, elapsed = ticks_while(lambda: scene.save(tmp_path / "scene"))
    # A thread sleeping 1 ms at a time ticks about once per 1 ms the save leaves it free. Ten
    # ticks need ten free milliseconds at least; a call that holds the GIL leaves the thread
    # one tick at most, however long it takes (a fast disk wrote this scene in 43 ms).
    assert during >= 10, (during, elapsed)
    assert scene.root == tmp_path / "scene" and np.array_equal(
        fluidnerf.load_scene(scene.root).images(), images
    )


def test_a_scene_is_saved_over_files_of_a_folder_only_when_asked(tmp_path):
    """Scene.save into a folder holding a user's images/frame_0000.tiff replaced that file
    with the scene's first image, without force=True and without a word."""
    K, poses = ring(3)
    scene = fluidnerf.scene_from_arrays(
        K, poses, np.ones((3, 16, 16), np.float32), np.array([[-10.0, -10, -10], [10, 10, 10]])
    )
    folder = tmp_path / "mine"
    (folder / "images").mkdir(parents=True)
    (folder / "images" / "frame_0000.tiff").write_text("the user's own image")
    with pytest.raises(
        fluidnerf.FluidNerfError, match="mine is not empty; save the scene into a new or empty"
    ):
        scene.save(folder)
    assert (folder / "images" / "frame_0000.tiff").read_text() == "the user's own image"
    assert sorted(p.name for p in folder.rglob("*")) == ["frame_0000.tiff", "images"]
    assert scene.root is None
    scene.save(folder, force=True)
    assert fluidnerf.load_scene(folder).root == folder.absolute()
    # An empty folder, or a new one, needs no force.
    (tmp_path / "empty").mkdir()
    scene.save(tmp_path / "empty")


def test_a_scene_that_cannot_be_saved_whole_leaves_its_folder_as_it_was(static_scene, tmp_path):
    """Scene.save wrote the images, then failed on the truth (here: no file may pass 16 kB, as
    on a full disk): a new folder was left half written, which a second attempt refused as not
    empty, and over an earlier scene (force=True) the earlier transforms.json was left naming the
    new images."""
    scene = fluidnerf.load_scene(static_scene.root)
    earlier = fluidnerf.scene_from_arrays(
        *ring(3), np.ones((3, 16, 16), np.float32), np.array([[-10.0, -10, -10], [10, 10, 10]])
    )
    over = tmp_path / "earlier"
    earlier.save(over)

    def save_limited(folder, force=False):
        limit = resource.getrlimit(resource.RLIMIT_FSIZE)
        handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        try:
            resource.setrlimit(resource.RLIMIT_FSIZE, (16_000, limit[1]))
            with pytest.raises(
                fluidnerf.FluidNerfError, match="cannot save the scene there: .*File too large"
            ):
                scene.save(folder, force=force)
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, limit)
            signal.signal(signal.SIGXFSZ, handler)

    dest = tmp_path / "new" / "copy"
    save_limited(dest)
    assert not (tmp_path / "new").exists()
    assert scene.root == static_scene.root
    save_limited(over, force=True)
    assert sorted(p.relative_to(over).as_posix() for p in over.rglob("*")) == [
        "images",
        "images/frame_0000.tiff",
        "images/frame_0001.tiff",
        "images/frame_0002.tiff",
        "transforms.json",
    ]
    np.testing.assert_array_equal(fluidnerf.load_scene(over).images(), earlier.images())
    scene.save(dest)
    again = fluidnerf.load_scene(dest)
    np.testing.assert_array_equal(again.images(), scene.images())
    assert [t for t, _ in again.truth()] == [t for t, _ in scene.truth()]


def test_bad_arrays_are_refused_naming_the_array_and_frame():
    K, poses = ring(3)
    images = np.ones((3, 16, 16), np.float32)
    aabb = np.array([[-10.0, -10, -10], [10, 10, 10]])
    with pytest.raises(fluidnerf.FluidNerfError, match=r"K: expected shape \(3, 3, 3\)"):
        fluidnerf.scene_from_arrays(K[:2], poses, images, aabb)
    bad = images.copy()
    bad[1, 4, 7] = -1.0
    with pytest.raises(fluidnerf.FluidNerfError, match=r"images\[1\]: pixel \(row 4, column 7\) is negative"):
        fluidnerf.scene_from_arrays(K, poses, bad, aabb)
    bad[1, 4, 7] = np.nan
    with pytest.raises(fluidnerf.FluidNerfError, match=r"images\[1\].*not finite"):
        fluidnerf.scene_from_arrays(K, poses, bad, aabb)
    # Accepted, and refused by every run naming the image file it saved into its own folder.
    bad[1, 4, 7] = 3e30
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"images\[1\]: pixel \(row 4, column 7\) is 3e30, above 1e18"
    ):
        fluidnerf.scene_from_arrays(K, poses, bad, aabb)
    with pytest.raises(fluidnerf.FluidNerfError, match="aabb"):
        fluidnerf.scene_from_arrays(K, poses, images, aabb[::-1])
    p = poses.copy()
    p[2, 3, 0] = 1.0
    with pytest.raises(fluidnerf.FluidNerfError, match=r"world_from_camera\[2\]"):
        fluidnerf.scene_from_arrays(K, p, images, aabb)
    with pytest.raises(ValueError, match="times: expected 3 values"):  # FluidNerfError is a ValueError
        fluidnerf.scene_from_arrays(K, poses, images, aabb, times=np.zeros(2))
    with pytest.raises(fluidnerf.FluidNerfError, match=r"distortion\[0\].*4, 5, 8"):
        fluidnerf.scene_from_arrays(K, poses, images, aabb, distortion=np.zeros((3, 3)))
    with pytest.raises(fluidnerf.FluidNerfError, match="transforms.json"):
        fluidnerf.load_scene("/nonexistent/scene")


def test_images_without_pixels_are_refused_as_the_images_problem():
    K, poses = ring(2, size=8)
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"^images: each image needs at least one pixel, got shape"
    ):
        fluidnerf.scene_from_arrays(K, poses, np.zeros((2, 8, 0), np.float32), [[-1, -1, -1], [1, 1, 1]])


def test_arrays_that_make_no_usable_scene_are_refused_when_given():
    """A scene from arrays was checked as a scene only when saved: a camera inside the box or
    blind to it, or a camera named twice, was refused naming a transforms.json the caller never
    wrote, after Scene.save had written it and the images."""
    K, poses = ring(3)
    images = np.ones((3, 16, 16), np.float32)
    for aabb, names, says in [
        (
            np.array([[-100.0, -100, -100], [100, 100, 100]]),
            None,
            r"frame 0 .*the camera centre .* is inside",
        ),
        (np.array([[1000.0, 1000, 1000], [1010, 1010, 1010]]), None, "does not see the reconstruction box"),
        (
            np.array([[-10.0, -10, -10], [10, 10, 10]]),
            ["a", "b", "a"],
            r"frames 0 and 2 are both camera \"a\"",
        ),
    ]:
        with pytest.raises(fluidnerf.FluidNerfError, match="^scene_from_arrays: .*" + says):
            fluidnerf.scene_from_arrays(K, poses, images, aabb, names=names)


def test_calibration_importers_read_the_library_fixtures():
    from conftest import REPO

    fixtures = REPO / "crates" / "io" / "tests" / "fixtures"
    cams = fluidnerf.read_opencv(fixtures / "opencv_two_cameras.yml")
    assert len(cams) == 2 and all(c.K.shape == (3, 3) and c.world_from_camera.shape == (4, 4) for c in cams)
    # A camera-to-world rotation is orthonormal with the last row [0, 0, 0, 1].
    for c in cams:
        r = c.world_from_camera[:3, :3]
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-9)
        np.testing.assert_array_equal(c.world_from_camera[3], [0, 0, 0, 1])
    colmap = fluidnerf.read_colmap(fixtures / "colmap")
    assert len(colmap) >= 1 and all(c.size[0] > 0 for c in colmap)


def test_a_scenes_own_arrays_and_lists_build_it_again(static_scene):
    """Scene.times gives None for every frame of a static scene; given back as times, they were
    cast to NaN and refused as "frame 0 has the time NaN". A None among numbers was refused as
    the NaN it became, too."""
    K, poses, dist, _ = static_scene.camera_arrays()
    again = fluidnerf.scene_from_arrays(
        K,
        poses,
        static_scene.images(),
        static_scene.aabb,
        times=static_scene.times,
        distortion=dist,
        holdout=static_scene.holdout,
        names=static_scene.names,
    )
    assert again.times == static_scene.times and again.holdout == static_scene.holdout
    with pytest.raises(TypeError, match=r"^times: element 1 \(flat index, C order\) is None; expected"):
        fluidnerf.scene_from_arrays(
            K[:2], poses[:2], static_scene.images()[:2], static_scene.aabb, times=[1.0, None]
        )
    with pytest.raises(TypeError, match=r"^estimate: element 1 \(flat index, C order\) is None"):
        fluidnerf.nrmse([1.0, None], [1.0, 2.0])


def test_cameras_compare_and_hash_as_values_and_their_matrices_are_read_only():
    from conftest import REPO

    file = REPO / "crates" / "io" / "tests" / "fixtures" / "opencv_two_cameras.yml"
    first, again = fluidnerf.read_opencv(file), fluidnerf.read_opencv(file)
    assert first == again and first[0] in again and first[0] != first[1]
    assert len({*first, *again}) == 2 and hash(first[0]) == hash(again[0])
    moved = first[0].world_from_camera.copy()
    moved[0, 3] += 1.0
    assert fluidnerf.Camera(first[0].name, first[0].K, moved, first[0].distortion, first[0].size) != first[0]
    with pytest.raises(ValueError, match="read-only"):
        first[0].K[0, 0] = 1.0
    with pytest.raises(fluidnerf.FluidNerfError, match=r"^K: expected shape \(3, 3\)"):
        fluidnerf.Camera("a", np.eye(4), np.eye(4), (), (8, 8))


def test_metashape_cameras_that_are_not_aligned_are_refused_unless_skipped(tmp_path):
    sensor = (
        '<sensor id="0" label="lens" type="frame"><resolution width="64" height="48"/>'
        '<calibration type="frame" class="adjusted"><f>80</f><cx>1.5</cx><p1>0.002</p1></calibration></sensor>'
    )
    pose = "<transform>1 0 0 0 0 1 0 0 0 0 1 -100 0 0 0 1</transform>"
    xml = tmp_path / "cameras.xml"
    xml.write_text(
        f'<document><chunk><sensors>{sensor}</sensors><cameras><camera id="0" sensor_id="0" label="a">{pose}'
        '</camera><camera id="1" sensor_id="0" label="b"/></cameras></chunk></document>'
    )
    with pytest.raises(fluidnerf.FluidNerfError, match="not aligned in Metashape.*b"):
        fluidnerf.read_metashape(xml)
    (cam,) = fluidnerf.read_metashape(xml, skip_unaligned=True)
    assert cam.name == "a" and cam.size == (64, 48)
    # A NumPy boolean was refused as "expected True or False, got np.True_"; an integer still is.
    assert [c.name for c in fluidnerf.read_metashape(xml, skip_unaligned=np.True_)] == ["a"]
    with pytest.raises(fluidnerf.FluidNerfError, match="not aligned in Metashape.*b"):
        fluidnerf.read_metashape(xml, skip_unaligned=np.False_)
    with pytest.raises(TypeError, match="skip_unaligned: expected True or False, got int 1"):
        fluidnerf.read_metashape(xml, skip_unaligned=1)
    # Offsets from the image centre with pixel centres at +0.5; Metashape's P1 is OpenCV's p2.
    np.testing.assert_allclose(cam.K[0], [80, 0, 33.0])
    assert cam.distortion[2:4] == (0.0, 0.002)


def test_arrays_of_the_wrong_dimension_are_refused_naming_the_array_and_its_shape(tmp_path):
    """Before, the extension raised "TypeError: argument 'images': 'ndarray' object cannot be
    converted to 'PyArray<T, D>'", which named neither the shape expected nor the one given,
    and a string for an array raised a ValueError that named no argument."""
    K, poses = ring(3)
    images = np.ones((3, 16, 16), np.float32)
    aabb = np.array([[-10.0, -10, -10], [10, 10, 10]])
    cases = [
        ({"images": images[0]}, r"images: expected shape \(N, H, W\), got an array of shape \(16, 16\)"),
        ({"K": K[0]}, r"K: expected shape \(N, 3, 3\), got an array of shape \(3, 3\)"),
        (
            {"world_from_camera": poses[..., None]},
            r"world_from_camera: expected shape \(N, 4, 4\), got .*\(3, 4, 4, 1\)",
        ),
        ({"aabb": aabb.ravel()}, r"aabb: expected shape \(2, 3\), got an array of shape \(6,\)"),
        ({"times": np.zeros((3, 1))}, r"times: expected shape \(N,\), got an array of shape \(3, 1\)"),
    ]
    for change, message in cases:
        args = {"K": K, "world_from_camera": poses, "images": images, "aabb": aabb, **change}
        with pytest.raises(fluidnerf.FluidNerfError, match=message):
            fluidnerf.scene_from_arrays(**args)
    with pytest.raises(TypeError, match=r"images: expected an array of numbers of shape \(N, H, W\)"):
        fluidnerf.scene_from_arrays(K, poses, "images", aabb)
    with pytest.raises(TypeError, match=r"images: expected an array of numbers of shape .*inhomogeneous"):
        fluidnerf.scene_from_arrays(K, poses, [images[0], images[0, :8], images[0]], aabb)
    scene = fluidnerf.scene_from_arrays(K, poses, images, aabb)
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"volume: expected shape \(nz, ny, nx\), got .*\(4, 4\)"
    ):
        fluidnerf.forward_project(scene, np.ones((4, 4), np.float32))
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"volume: expected shape \(nz, ny, nx\), got .*\(1, 4, 4, 4\)"
    ):
        fluidnerf.render(scene, np.ones((1, 4, 4, 4), np.float32))
    (tmp_path / "volume.npy").write_bytes(b"")
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"aabb: expected shape \(2, 3\), got an array of shape \(6,\)"
    ):
        fluidnerf.open_run(tmp_path, aabb=aabb.ravel())


def test_a_single_number_or_none_for_an_array_is_refused_as_given():
    """A 0-d array, a number or None given for an array was reported as "got an array of shape
    (1,)": np.ascontiguousarray made it one, and None read as NaN."""
    K, poses = ring(3)
    images = np.ones((3, 16, 16), np.float32)
    aabb = np.array([[-10.0, -10, -10], [10, 10, 10]])
    cases = [
        ({"K": np.array(3.0)}, r"K: expected shape \(N, 3, 3\), got an array of shape \(\)$"),
        ({"K": np.float64(3.0)}, r"K: expected shape \(N, 3, 3\), got float64 3.0, which is no array$"),
        ({"images": 1.0}, r"images: expected shape \(N, H, W\), got float 1.0, which is no array$"),
        ({"times": 5}, r"times: expected shape \(N,\), got int 5, which is no array$"),
        (
            {"distortion": 0.1},
            r"distortion: expected shape \(N, 4\|5\|8\), got float 0.1, which is no array$",
        ),
    ]
    for change, message in cases:
        args = {"K": K, "world_from_camera": poses, "images": images, "aabb": aabb, **change}
        with pytest.raises(fluidnerf.FluidNerfError, match=message):
            fluidnerf.scene_from_arrays(**args)
    with pytest.raises(TypeError, match=r"K: expected an array of numbers of shape \(N, 3, 3\), got None$"):
        fluidnerf.scene_from_arrays(None, poses, images, aabb)
    scene = fluidnerf.scene_from_arrays(K, poses, images, aabb)
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"volume: expected shape \(nz, ny, nx\), got an array of shape \(\)"
    ):
        fluidnerf.forward_project(scene, np.array(1.0, np.float32))
    with pytest.raises(fluidnerf.FluidNerfError, match=r"differ in shape: \[\] and \[3\]"):
        fluidnerf.nrmse(np.float32(1), np.ones(3))
    with pytest.raises(TypeError, match="truth: expected an array of numbers, got None"):
        fluidnerf.nrmse(np.ones(3), None)
    # Arrays that are not C-ordered are still read as they are.
    fortran = fluidnerf.scene_from_arrays(K, poses, np.asfortranarray(images[:, ::-1]), aabb)
    np.testing.assert_array_equal(fortran.images(), images[:, ::-1])


def test_a_run_that_records_its_box_is_not_placed_in_another(static_scene, tmp_path):
    """open_run(folder, aabb=...) of a run with a report put it in the run's own box and
    ignored the one given, without a word: the box given was never the results'."""
    run = fluidnerf.reconstruct(static_scene, "asart", tmp_path / "run", resolution=8, progress=False)
    other = run.aabb / 2
    with pytest.raises(
        fluidnerf.FluidNerfError,
        match=r"aabb: .*run records the box its results fill, \[-20.0, .* not the one given",
    ):
        fluidnerf.open_run(run.path, aabb=other)
    np.testing.assert_array_equal(fluidnerf.open_run(run.path, aabb=run.aabb).aabb, run.aabb)
    # A bare volume.npy is placed by the box given.
    (tmp_path / "bare").mkdir()
    np.save(tmp_path / "bare" / "volume.npy", run.volume)
    np.testing.assert_array_equal(fluidnerf.open_run(tmp_path / "bare", aabb=other).aabb, other)


def test_numbers_of_the_wrong_type_are_refused_naming_the_argument(tmp_path):
    """intensity_scale="x" raised float()'s "could not convert string to float: 'x'", which
    named no argument, and synth(seed=3.7) ran with seed 3."""
    K, poses = ring(3)
    images = np.ones((3, 16, 16), np.float32)
    aabb = np.array([[-10.0, -10, -10], [10, 10, 10]])
    with pytest.raises(TypeError, match="intensity_scale: expected a number, got 'x'"):
        fluidnerf.scene_from_arrays(K, poses, images, aabb, intensity_scale="x")
    with pytest.raises(TypeError, match="seed: expected an integer, got 3.7"):
        fluidnerf.synth(tmp_path / "s", "demo", seed=3.7)
    assert not (tmp_path / "s").exists()


def test_a_path_that_is_no_path_is_refused_naming_the_argument(static_scene, tmp_path):
    """A scene, folder or output given as a number raised os.fspath's "expected str, bytes or
    os.PathLike object, not int", which named no argument."""
    vol = np.ones((4, 4, 4), np.float32)
    with pytest.raises(TypeError, match="scene: expected a Scene or the path of a scene folder, got int 3"):
        fluidnerf.forward_project(3, vol)
    path = r"expected a path \(a string or os.PathLike\), got"
    calls = [
        (lambda: fluidnerf.load_scene(3), f"folder: {path} int 3"),
        (lambda: fluidnerf.open_run(None), f"folder: {path} NoneType None"),
        (lambda: fluidnerf.read_transforms(1.5), f"path: {path} float 1.5"),
        (lambda: fluidnerf.synth(["s"], "demo"), rf"folder: {path} list \['s'\]"),
        (lambda: fluidnerf.reconstruct(static_scene, "asart", 7, resolution=8), f"out: {path} int 7"),
    ]
    for call, message in calls:
        with pytest.raises(TypeError, match=message):
            call()
    assert fluidnerf.load_scene(os.fsencode(static_scene.root)).root == static_scene.root


def test_an_empty_path_is_refused_naming_the_argument(static_scene, tmp_path, monkeypatch):
    """An empty string stood for the current folder: synth wrote its scene there although it
    held files, reconstruct wrote its run there, and Scene.save said "cannot make an empty
    path absolute"."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.txt").write_text("mine")
    small = {"resolution": 8, "lens": {"resolution": [12, 12]}, "rig": {"layout": {"count": 3}}}
    K, poses = ring(3)
    scene = fluidnerf.scene_from_arrays(K, poses, np.ones((3, 16, 16), np.float32), [[-10] * 3, [10] * 3])
    calls = [
        (lambda: fluidnerf.synth("", "demo", **small), "folder"),
        (lambda: fluidnerf.reconstruct(static_scene, "asart", "", resolution=8), "out"),
        (lambda: fluidnerf.build_config(static_scene, config=""), "config"),
        (lambda: fluidnerf.load_scene(b""), "folder"),
        (lambda: fluidnerf.read_davis(""), "path"),
        (lambda: scene.save(""), "folder"),
    ]
    for call, name in calls:
        with pytest.raises(fluidnerf.FluidNerfError, match=f"^{name}: the path is empty"):
            call()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]


def test_hold_out_flags_and_complex_images_are_refused_naming_the_argument():
    """holdout="yes" was read as three flags ("expected 3 entries"), a flag of "no" as True,
    and complex images lost their imaginary part with only NumPy's warning."""
    K, poses = ring(3)
    images = np.ones((3, 16, 16), np.float32)
    aabb = np.array([[-10.0, -10, -10], [10, 10, 10]])
    with pytest.raises(
        TypeError, match="holdout: expected a sequence of booleans, one per frame, got the string 'yes'"
    ):
        fluidnerf.scene_from_arrays(K, poses, images, aabb, holdout="yes")
    with pytest.raises(TypeError, match=r"holdout\[1\]: expected a boolean, got str 'no'"):
        fluidnerf.scene_from_arrays(K, poses, images, aabb, holdout=[False, "no", True])
    with pytest.raises(
        TypeError, match=r"images: expected real numbers of shape \(N, H, W\), got complex ones"
    ):
        fluidnerf.scene_from_arrays(K, poses, images.astype(np.complex64), aabb)
    scene = fluidnerf.scene_from_arrays(K, poses, images, aabb, holdout=[0, np.bool_(True), False])
    assert scene is not None


def test_hold_out_flags_and_names_that_are_no_sequence_are_refused_naming_the_argument():
    """holdout=5 raised a bare "'int' object is not iterable", naming no argument, and
    names="abc" the extension's "argument 'names': Can't extract `str` to `Vec`"."""
    K, poses = ring(3)
    images = np.ones((3, 16, 16), np.float32)
    aabb = np.array([[-10.0, -10, -10], [10, 10, 10]])
    flags = r"holdout: expected a sequence of booleans, one per frame, got"
    for value, shown in [
        (5, "int 5"),
        (2.5, "float 2.5"),
        (np.array(True), "ndarray array"),
        ({0: True}, r"dict \{0: True\}"),
    ]:
        with pytest.raises(TypeError, match=f"{flags} {shown}"):
            fluidnerf.scene_from_arrays(K, poses, images, aabb, holdout=value)
    names = r"names: expected a sequence of camera names \(strings or None\), one per frame, got"
    for value, shown in [(5, "int 5"), ("abc", "the string 'abc'"), ({"a", "b", "c"}, "set")]:
        with pytest.raises(TypeError, match=f"{names} {shown}"):
            fluidnerf.scene_from_arrays(K, poses, images, aabb, names=value)
    with pytest.raises(
        TypeError, match=r"names\[1\]: expected a camera name \(a string\) or None, got int 2"
    ):
        fluidnerf.scene_from_arrays(K, poses, images, aabb, names=["a", 2, "c"])
    scene = fluidnerf.scene_from_arrays(
        K, poses, images, aabb, holdout=np.array([False, True, False]), names=np.array(["a", "b", "c"])
    )
    assert scene.holdout == [False, True, False] and scene.names == ["a", "b", "c"]
    assert fluidnerf.scene_from_arrays(K, poses, images, aabb, names=("a", None, "c")).names == [
        "a",
        None,
        "c",
    ]


def test_a_scene_without_frames_is_refused():
    """Zero frames made a scene that nothing could use: saving it, loading it back and
    projecting through it failed later, each with its own message, and render returned []."""
    K, poses = ring(3)
    aabb = np.array([[-10.0, -10, -10], [10, 10, 10]])
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"images: a scene needs at least one frame, .*\(0, 16, 16\)"
    ):
        fluidnerf.scene_from_arrays(K[:0], poses[:0], np.ones((0, 16, 16), np.float32), aabb)


def test_ctrl_c_stops_a_synthesis_before_it_writes_anything(tmp_path):
    """The synthesis took no Ctrl-C: a rig of hundreds of thin-lens cameras ran to its end (about
    12 s here) with the interpreter deaf to SIGINT, then wrote every file."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT))
    try:
        started = time.monotonic()
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            fluidnerf.synth(tmp_path / "big", "demo", rig={"layout": {"count": 300}})
        timer.join()
    finally:
        signal.signal(signal.SIGINT, previous)
    assert time.monotonic() - started < 4
    assert not (tmp_path / "big" / "transforms.json").exists()


def test_synth_records_the_preprocessing_its_images_need(tmp_path):
    """Python's synth wrote every scene as 16-bit counts without preprocessing keys: a dark
    offset was read as light, and a real-like recording lost its background frames and was
    refused on its JPEG's name."""
    small = {
        "resolution": 12,
        "lens": {"resolution": [16, 16]},
        "rig": {"layout": {"count": 3}, "holdout": []},
    }
    fluidnerf.synth(tmp_path / "offset", "demo", sensor={"dark_offset": 500.0}, **small)
    scene = json.loads((tmp_path / "offset" / "transforms.json").read_text())
    backgrounds = [f.get("background", scene.get("background")) for f in scene["frames"]]
    assert backgrounds == [500.0] * 3
    assert scene["flow_axis"] == [1.0, 0.0, 0.0]

    fluidnerf.synth(tmp_path / "real", "real-like-small", **small)
    scene = json.loads((tmp_path / "real" / "transforms.json").read_text())
    assert scene["linearisation"] == "srgb"
    for f in scene["frames"]:
        assert f["file_path"].endswith(".jpg")
        for b in f["background"]:
            assert (tmp_path / "real" / b).is_file()


def test_synth_writes_the_scene_and_its_records_as_the_command_writes_them(tmp_path, cli):
    """Python's synth wrote no ``preview.png``, and a ``synth.json`` without ``camera_gains``
    (the one record of a real-like recording's true gains), ``counts``, ``phantom_note`` and
    ``seconds``. The same preset and seed write the same files and the same records (but for
    the time taken)."""
    fluidnerf.synth(
        tmp_path / "py",
        "real-like-small",
        seed=3,
        resolution=12,
        lens={"resolution": [12, 12]},
        rig={"layout": {"count": 4}, "holdout": [1]},
    )
    command = ["synth", "-p", "real-like-small", "--seed", "3", "--resolution", "12", "--pixels", "12"]
    command += ["--cameras", "4", "--holdout", "1", "-o", str(tmp_path / "cli")]
    done = subprocess.run([cli, "-q", *command], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr

    def files(root: Path) -> list[str]:
        return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())

    assert files(tmp_path / "py") == files(tmp_path / "cli")
    assert "preview.png" in files(tmp_path / "py") and "background/cam000_b0.jpg" in files(tmp_path / "py")
    py, made = (json.loads((tmp_path / f / "synth.json").read_text()) for f in ("py", "cli"))
    assert list(py) == list(made)
    assert sorted(py["camera_gains"]) == ["cam000", "cam001", "cam002", "cam003"]

    def untimed(record: dict) -> dict:
        stats = {k: v for k, v in record["stats"].items() if not k.endswith("seconds")}
        return {**record, "seconds": None, "stats": stats}

    assert untimed(py) == untimed(made)


def test_a_scene_is_read_through_its_flat_fields(tmp_path):
    """A real-like recording through vignetting names its flat-field frames (``flat_field``),
    and its images are read divided by them: they come back to the images recorded without
    vignetting, where without the key they keep the vignetting. A saved copy holds the
    corrected images and no flat field."""
    small = {
        "resolution": 12,
        "lens": {"resolution": [16, 16]},
        "rig": {"layout": {"count": 3}, "holdout": []},
    }
    plain = fluidnerf.synth(tmp_path / "plain", "real-like-small", **small)
    real = {"vignetting": 0.8, "flat_frames": 2}
    vignetted = fluidnerf.synth(tmp_path / "vignetted", "real-like-small", real=real, **small)
    scene = json.loads((tmp_path / "vignetted" / "transforms.json").read_text())
    assert scene["frames"][0]["flat_field"] == ["flat/cam000_f0.jpg", "flat/cam000_f1.jpg"]
    reference = plain.images()

    def off(images: np.ndarray) -> float:
        return float(np.linalg.norm(images - reference) / np.linalg.norm(reference))

    # Measured: 0.026 with the flat fields (noise and JPEG error, amplified in the dim corners),
    # 0.19 without.
    corrected = vignetted.images()
    assert off(corrected) < 0.05
    vignetted.save(tmp_path / "copy")
    saved = json.loads((tmp_path / "copy" / "transforms.json").read_text())
    assert all("flat_field" not in f for f in saved["frames"])
    np.testing.assert_allclose(fluidnerf.Scene.load(tmp_path / "copy").images(), corrected, rtol=1e-6)

    for f in scene["frames"]:
        del f["flat_field"]
    (tmp_path / "vignetted" / "transforms.json").write_text(json.dumps(scene))
    assert off(fluidnerf.Scene.load(tmp_path / "vignetted").images()) > 0.15


def test_a_bad_flat_field_is_refused_naming_the_file_and_frame(tmp_path, static_scene):
    """A flat field of another size than its frame's image is refused when the images are
    read, naming the flat's file and the frame; an empty list when the scene is loaded."""
    folder = tmp_path / "scene"
    shutil.copytree(static_scene.root, folder)
    scene = json.loads((folder / "transforms.json").read_text())
    scene["flat_field"] = "preview.png"
    (folder / "transforms.json").write_text(json.dumps(scene))
    with pytest.raises(fluidnerf.FluidNerfError, match=r"preview\.png") as refused:
        fluidnerf.Scene.load(folder).images()
    assert "frame 0 (" in str(refused.value) and "`flat_field` image" in str(refused.value)
    scene["flat_field"] = []
    (folder / "transforms.json").write_text(json.dumps(scene))
    with pytest.raises(fluidnerf.FluidNerfError, match=r"top level, key `flat_field`: is an empty list"):
        fluidnerf.Scene.load(folder)


def test_synth_refuses_a_run_folder_and_a_users_files_as_the_command_does(tmp_path, static_scene):
    """Python's synth wrote its scene into any folder: among a run's files, and over a user's
    images of the names it writes, where ``fluidnerf synth`` refuses both."""
    small = {"resolution": 8, "lens": {"resolution": [12, 12]}, "rig": {"layout": {"count": 3}}}
    run = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "run", resolution=8, stopping={"max_iterations": 1}, progress=False
    )
    before = sorted(p.name for p in run.path.iterdir())
    with pytest.raises(fluidnerf.FluidNerfError, match="run"):
        fluidnerf.synth(run.path, "demo", **small)
    assert sorted(p.name for p in run.path.iterdir()) == before
    mine = tmp_path / "mine"
    (mine / "images").mkdir(parents=True)
    (mine / "images" / "cam000.png").write_text("mine")
    with pytest.raises(fluidnerf.FluidNerfError, match="is not empty; .* or pass force=True"):
        fluidnerf.synth(mine, "demo", **small)
    assert (mine / "images" / "cam000.png").read_text() == "mine"
    fluidnerf.synth(mine, "demo", force=True, **small)
    assert (mine / "transforms.json").is_file()


def test_a_transforms_json_read_in_another_box_is_a_scene_of_its_own(tmp_path, static_scene):
    """read_transforms(aabb=...) gave a scene said to live in the file's folder, in a box the file
    does not hold: a run recorded that folder as its scene, so its config.json reran in the
    file's box (or not at all, for a file without one), and the file's truth stood in the new box."""
    folder = Path(static_scene.root)
    box = np.array([[-10.0, -10.0, -10.0], [10.0, 10.0, 10.0]])
    with pytest.raises(fluidnerf.FluidNerfError, match=r"aabb: the truth volume\(s\) of .* fill its box"):
        fluidnerf.read_transforms(folder, aabb=box)
    # A file without a box (as NeRF tools write it) and without truth.
    nerf = tmp_path / "nerf"
    shutil.copytree(folder, nerf)
    meta = json.loads((nerf / "transforms.json").read_text())
    own = np.array(meta.pop("aabb"))
    meta.pop("truth")
    (nerf / "transforms.json").write_text(json.dumps(meta))
    scene = fluidnerf.read_transforms(nerf, aabb=own)
    assert scene.root is None and "in memory" in repr(scene)
    run = fluidnerf.reconstruct(
        scene, "asart", tmp_path / "run", resolution=8, stopping={"max_iterations": 1}, progress=False
    )
    recorded = Path(json.loads((run.path / "config.json").read_text())["scene"])
    assert recorded == (tmp_path / "run" / "scene").absolute()
    np.testing.assert_array_equal(fluidnerf.load_scene(recorded).aabb, own)
    # The file's own box, given again, is the file's scene.
    assert fluidnerf.read_transforms(folder, aabb=static_scene.aabb).root == folder


def _png8(path, pixels: np.ndarray) -> None:
    """An 8-bit grayscale PNG of ``pixels`` (H, W)."""
    import struct
    import zlib

    h, w = pixels.shape
    raw = b"".join(b"\x00" + pixels[r].astype(np.uint8).tobytes() for r in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
        )

    header = struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )


def test_a_saved_copy_keeps_the_masks_and_flow_axis_of_its_recording(tmp_path):
    """scene.save wrote the images but dropped their masks and the flow axis: a copy of a scene
    whose recording masks a reflection out reconstructed from the masked pixels too."""
    scene = fluidnerf.synth(
        tmp_path / "scene", "demo", resolution=12, lens={"resolution": [12, 12]}, rig={"layout": {"count": 3}}
    )
    mask = np.full((12, 12), 255, np.uint8)
    mask[:5] = 0
    _png8(tmp_path / "scene" / "mask1.png", mask)
    file = tmp_path / "scene" / "transforms.json"
    meta = json.loads(file.read_text())
    meta["frames"][1]["mask_path"] = "mask1.png"
    meta["flow_axis"] = [0.0, 1.0, 0.0]
    file.write_text(json.dumps(meta))
    scene = fluidnerf.load_scene(tmp_path / "scene")
    scene.save(tmp_path / "copy")
    copied = json.loads((tmp_path / "copy" / "transforms.json").read_text())
    assert copied["flow_axis"] == [0.0, 1.0, 0.0]
    assert "mask_path" not in copied["frames"][0] and "mask_path" not in copied["frames"][2]
    assert copied["frames"][1]["mask_path"] == "masks/frame_0001.png"
    np.testing.assert_array_equal(fluidnerf.load_scene(tmp_path / "copy").images(), scene.images())
    options = {"resolution": 8, "stopping": {"max_iterations": 2}, "progress": False}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a = fluidnerf.reconstruct(scene, "asart", tmp_path / "a", **options)
    b = fluidnerf.reconstruct(tmp_path / "copy", "asart", tmp_path / "b", **options)
    np.testing.assert_array_equal(a.volume, b.volume)
    # The masked image's total is not compared with the others' as a sign of another gain.
    assert not [w for w in caught if "differ between cameras" in str(w.message)]


FIXTURES = Path(__file__).resolve().parents[2] / "crates" / "io" / "tests" / "fixtures" / "video"


def test_read_video_decodes_high_speed_recordings_and_mjpeg_as_import_does():
    # The fixtures' pixel (x, y) of frame k is v = 20 + 4x + 3y + 10k; the 12-bit MRAW and
    # the 16-bit cine store 64 + 10 v (the cine's black level is 64).
    y, x = np.mgrid[0:24, 0:32]
    frames, times, info = fluidnerf.read_video(FIXTURES / "ramp_12bit.mraw", start=1, every=2)
    assert frames.shape == (2, 24, 32) and frames.dtype == np.float32
    np.testing.assert_array_equal(times, [0.001, 0.003])
    np.testing.assert_array_equal(frames[1], 64 + 10 * (20 + 4 * x + 3 * y + 30))
    assert (info["decoder"], info["range_source"], info["frames_kept"]) == ("mraw", "raw", 2)
    frames, times, info = fluidnerf.read_video(str(FIXTURES / "ramp_16bit.cine"), end=2, time_offset=1.0)
    np.testing.assert_array_equal(frames[0], 10 * (20 + 4 * x + 3 * y))
    np.testing.assert_array_equal(times, [1.0, 1.001])
    # The same counts packed at 12 bits per pixel.
    packed, packed_times, info = fluidnerf.read_video(
        FIXTURES / "ramp_12bit_packed.cine", end=2, time_offset=1.0
    )
    np.testing.assert_array_equal(packed, frames)
    np.testing.assert_array_equal(packed_times, times)
    assert info["decoder"] == "cine"
    # MJPEG, linearised as asked: the ramp within JPEG's error, then through the sRGB curve.
    frames, times, info = fluidnerf.read_video(FIXTURES / "ramp_mjpeg.avi", linearisation="srgb")
    c = (20 + 4 * 5 + 3 * 7 + 10) / 255
    assert info["decoder"] == "mjpeg-avi" and frames.shape == (4, 24, 32)
    assert abs(frames[1, 7, 5] - 255 * ((c + 0.055) / 1.055) ** 2.4) < 1.0
    np.testing.assert_allclose(times, [0.0, 0.1, 0.2, 0.3])


@pytest.mark.parametrize(
    ("kwargs", "error", "words"),
    [
        ({"start": -1}, ValueError, "start: -1 is negative"),
        ({"every": 0}, ValueError, "every: 0"),
        ({"start": 2, "end": 2}, ValueError, "end: 2 is not after start 2"),
        ({"end": 9}, fluidnerf.FluidNerfError, "has only 4 frame(s)"),
        ({"time_offset": float("nan")}, ValueError, "time_offset: nan"),
        ({"range": "tv-ish"}, fluidnerf.FluidNerfError, "range: expected auto, full or limited"),
        ({"linearisation": "-1"}, fluidnerf.FluidNerfError, "linearisation: `-1` is not a linearisation"),
        ({"start": 1.0}, TypeError, "start: expected an integer"),
    ],
)
def test_read_video_refuses_a_bad_selection_naming_it(kwargs, error, words):
    with pytest.raises(error, match=None) as e:
        fluidnerf.read_video(FIXTURES / "ramp_8bit.mraw", **kwargs)
    assert words in str(e.value)


@pytest.mark.parametrize("name", ["ramp_8bit.mraw", "ramp_16bit.cine"])
def test_read_video_refuses_a_range_or_linearisation_a_raw_recording_ignores(name):
    """A cine's or MRAW's linear counts were returned as they are for linearisation="srgb" or
    range="limited", as if either had been applied."""
    for kwargs, words in [
        ({"linearisation": "srgb"}, "linearisation: `srgb` does not apply to"),
        ({"linearisation": "2.2"}, "linearisation: `2.2` does not apply to"),
        ({"range": "limited"}, "range: the limited range does not apply to"),
    ]:
        with pytest.raises(fluidnerf.FluidNerfError, match=None) as e:
            fluidnerf.read_video(FIXTURES / name, **kwargs)
        assert words in str(e.value) and name in str(e.value) and "sensor's linear counts" in str(e.value)
    for kwargs in ({"linearisation": "linear"}, {"range": "full"}, {"range": "auto"}):
        assert fluidnerf.read_video(FIXTURES / name, **kwargs)[0].shape == (4, 24, 32)


def test_read_video_names_the_file_it_cannot_read(tmp_path):
    (tmp_path / "cam.mraw").write_bytes(b"\0" * 10)
    with pytest.raises(fluidnerf.FluidNerfError, match="cam.mraw.*no header of its own"):
        fluidnerf.read_video(tmp_path / "cam.mraw")
    with pytest.raises(TypeError, match="path: expected a path"):
        fluidnerf.read_video(3)


DAVIS = FIXTURES.parent / "davis"


def _readim_values() -> dict:
    """The fixtures' frames and camera labels as LaVision's ReadIM read them back
    (`make_davis_with_readim.py` recorded them in `make_davis_with_readim.txt`)."""
    files, current = {}, None
    for line in (DAVIS / "make_davis_with_readim.txt").read_text().splitlines():
        words = line.split()
        if words[0] == "frame":
            current["frames"].append([float(v) for v in words[2:]])
        else:
            keys = dict(zip(words[1::2], words[2::2]))
            labels = [None if c == "-" else c for c in keys["cameras"].split(",")]
            current = {"shape": (int(keys["height"]), int(keys["width"])), "labels": labels, "frames": []}
            files[words[0]] = current
    return files


@pytest.mark.parametrize("name", ["three_cameras_imx.im7", "float.im7", "zlib.im7", "word_old.imx"])
def test_read_davis_gives_readims_frames_and_labels(name):
    expected = _readim_values()[name]
    frames, labels, attributes = fluidnerf.read_davis(DAVIS / name)
    assert frames.dtype == np.float32
    assert frames.shape == (len(expected["frames"]), *expected["shape"])
    want = np.array(expected["frames"], dtype=np.float32).reshape(frames.shape)
    np.testing.assert_array_equal(frames, want)
    # A file without camera names has one unnamed frame per "-".
    assert labels == expected["labels"]
    assert isinstance(attributes, dict)
    if any(labels):
        assert all(f"CameraName{k}" in attributes for k in range(len(labels)))


def test_a_scene_whose_files_are_cut_short_or_empty_says_so_naming_them(tmp_path, static_scene):
    folder = tmp_path / "copy"
    shutil.copytree(static_scene.root, folder)
    truth = folder / "truth" / "truth.npy"
    data = truth.read_bytes()
    # Short by less than the .npy header's length: it failed half way, "failed to fill whole buffer".
    truth.write_bytes(data[:-4])
    with pytest.raises(
        fluidnerf.FluidNerfError, match="truth.npy: shape .* needs .* bytes of data, but .* follow"
    ):
        fluidnerf.load_scene(folder).truth()
    truth.write_bytes(data)
    image = folder / json.loads((folder / "transforms.json").read_text())["frames"][1]["file_path"]
    image.write_bytes(b"")
    with pytest.raises(fluidnerf.FluidNerfError, match=r"the image file is empty \(0 bytes\)") as e:
        fluidnerf.load_scene(folder).images()
    assert image.name in str(e.value)


def test_a_folder_where_the_scene_file_goes_is_refused_even_with_force(tmp_path, static_scene):
    folder = tmp_path / "out"
    (folder / "transforms.json").mkdir(parents=True)
    for force in (False, True):
        with pytest.raises(
            fluidnerf.FluidNerfError, match="transforms.json: is a folder, where the scene file goes"
        ):
            static_scene.save(folder, force=force)
        with pytest.raises(
            fluidnerf.FluidNerfError, match="transforms.json: is a folder, where the scene file goes"
        ):
            fluidnerf.synth(folder, "demo", resolution=8, force=force)
    assert sorted(p.name for p in folder.iterdir()) == ["transforms.json"]


def test_read_davis_refuses_a_truncated_file_naming_it(tmp_path):
    short = tmp_path / "short.im7"
    short.write_bytes((DAVIS / "word.im7").read_bytes()[:300])
    with pytest.raises(fluidnerf.FluidNerfError, match=None) as e:
        fluidnerf.read_davis(short)
    assert "short.im7" in str(e.value)


def test_units_that_are_no_string_are_refused_naming_the_argument():
    """units=5 raised pyo3's "argument 'units': 'int' object cannot be converted to 'PyString'"."""
    K, poses = ring(4)
    images = np.ones((4, 16, 16), np.float32)
    aabb = np.array([[-10.0, -10.0, -10.0], [10.0, 10.0, 10.0]])
    for units in (5, None, b"mm"):
        with pytest.raises(TypeError, match=rf"^units: expected a string, got {type(units).__name__} "):
            fluidnerf.scene_from_arrays(K, poses, images, aabb, units=units)


def _rotation(axis, angle):
    """Rodrigues' formula, written out here independently of the library."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def test_projection_matrices_give_back_their_cameras(tmp_path):
    K = np.array([[812.5, 1.25, 330.75], [0, 790.25, 236.5], [0, 0, 1]])
    R, t = _rotation([0.3, -1, 0.2], 2.1), np.array([0.5, -0.25, 700.0])
    P = K @ np.hstack([R, t[:, None]])
    np.savetxt(tmp_path / "left.txt", -2.5 * P)  # any scale and sign
    (cam,) = fluidnerf.read_projection(tmp_path / "left.txt", (640, 480))
    assert cam.name == "left" and cam.size == (640, 480) and all(d == 0 for d in cam.distortion)
    np.testing.assert_allclose(cam.K, K, rtol=1e-10)
    camera_from_world = np.linalg.inv(cam.world_from_camera)
    np.testing.assert_allclose(camera_from_world[:3, :3], R, atol=1e-12)
    np.testing.assert_allclose(camera_from_world[:3, 3], t, rtol=1e-10)
    # Points project where the matrix puts them.
    X = np.array([[0, 0, 0, 1], [30, -20, 50, 1], [-45, 10, -60, 1.0]]).T
    uv = (P @ X)[:2] / (P @ X)[2]
    xc = camera_from_world[:3] @ X
    np.testing.assert_allclose((cam.K @ xc)[:2] / xc[2], uv, atol=1e-9)

    # DLT coefficients of two cameras, one per column, v counted up from the bottom.
    R2 = _rotation([1, 0.1, 0], -0.4)
    P2 = K @ np.hstack([R2, np.array([[-12.0], [3.0], [250.0]])])
    flip = np.array([[1, 0, 0], [0, -1, 480], [0, 0, 1.0]])
    cols = [(flip @ p).ravel()[:11] / (flip @ p)[2, 3] for p in (P, P2)]
    np.savetxt(tmp_path / "rig_dltCoefs.csv", np.array(cols).T, delimiter=",", header="a,b", comments="")
    cams = fluidnerf.read_projection(tmp_path / "rig_dltCoefs.csv", {"a": (640, 480), "b": (640, 480)}, True)
    assert [c.name for c in cams] == ["a", "b"]
    np.testing.assert_allclose(cams[1].K, K, rtol=1e-9)

    with pytest.raises(fluidnerf.FluidNerfError, match="camera `b`: a projection matrix holds no image size"):
        fluidnerf.read_projection(tmp_path / "rig_dltCoefs.csv", {"a": (640, 480)})
    with pytest.raises(fluidnerf.FluidNerfError, match="names camera `c`, which .* does not hold"):
        fluidnerf.read_projection(tmp_path / "rig_dltCoefs.csv", {"a": (1, 1), "b": (1, 1), "c": (1, 1)})
    for bad in [(640,), (0, 480), (640.0, 480), "640x480", (True, 480)]:
        with pytest.raises(fluidnerf.FluidNerfError, match="image_size: expected an image size"):
            fluidnerf.read_projection(tmp_path / "left.txt", bad)
    (tmp_path / "singular.txt").write_text("1 2 3 4\n2 4 6 8\n0 0 1 1\n")
    with pytest.raises(fluidnerf.FluidNerfError, match="singular.txt: camera `singular`: .*singular"):
        fluidnerf.read_projection(tmp_path / "singular.txt", (64, 64))


def test_an_image_size_given_as_a_numpy_array_is_taken(tmp_path):
    """The sizes of `Scene.camera_arrays()` are a NumPy array; a row of it, `(640, 480)` as
    np.array([640, 480]), was refused as "expected an image size (width, height) of positive
    integers", which it is."""
    K = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    np.savetxt(tmp_path / "left.txt", K @ np.hstack([np.eye(3), [[0.0], [0.0], [500.0]]]))
    for size in (np.array([640, 480]), np.array([640, 480], dtype=np.uint16)):
        (cam,) = fluidnerf.read_projection(tmp_path / "left.txt", size)
        assert cam.size == (640, 480) and type(cam.size[0]) is int
        (cam,) = fluidnerf.read_projection(tmp_path / "left.txt", {"left": size})
        assert cam.size == (640, 480)
    for bad in (
        np.array([640.0, 480.0]),
        np.array([[640, 480]]),
        np.array([640, 480, 1]),
        np.array([640, -480]),
    ):
        with pytest.raises(fluidnerf.FluidNerfError, match="image_size: expected an image size"):
            fluidnerf.read_projection(tmp_path / "left.txt", bad)


def test_a_scene_saved_over_another_takes_the_records_of_the_other_away(tmp_path):
    """Saved with force=True over a synthetic scene, a scene left that scene's synth.json beside
    its own transforms.json: the record of a phantom, truth and cameras no longer there, which
    `fluidnerf study` took for the scene's. Saved over its own folder, a scene keeps it."""
    folder = tmp_path / "synthetic"
    fluidnerf.synth(folder, "demo", resolution=8, lens={"resolution": [8, 8]}, rig={"layout": {"count": 3}})
    (folder / "preview.png").write_bytes(b"the preview `fluidnerf synth` draws")
    fluidnerf.load_scene(folder).save(folder, force=True)
    assert (folder / "synth.json").is_file() and (folder / "preview.png").is_file()
    K, poses = ring(3)
    scene = fluidnerf.scene_from_arrays(
        K, poses, np.ones((3, 16, 16), np.float32), np.array([[-10.0, -10, -10], [10, 10, 10]])
    )
    scene.save(folder, force=True)
    assert not (folder / "synth.json").exists() and not (folder / "preview.png").exists()
    assert fluidnerf.load_scene(folder).images().shape == (3, 16, 16)


def test_read_video_names_a_davis_image_for_what_it_is():
    """A DaVis image given to read_video was sent to ffmpeg, and refused as "decoding this video
    needs ffmpeg": installing ffmpeg, which reads no DaVis file, would not have read it."""
    with pytest.raises(fluidnerf.FluidNerfError, match=None) as e:
        fluidnerf.read_video(DAVIS / "float.im7")
    assert "float.im7: is a LaVision DaVis image" in str(e.value) and "read_davis" in str(e.value)
    assert "ffmpeg" not in str(e.value)


def test_a_scenes_repr_says_static_or_how_many_times(static_scene, tr_scene):
    """A static scene read as having "0 times"."""
    assert repr(static_scene).startswith("Scene(8 frames, static, box ")
    assert repr(tr_scene).startswith("Scene(25 frames, 5 times, box ")
