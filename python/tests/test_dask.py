"""Scale-out on Dask: a 4-window time-resolved run on a LocalCluster of 2 single-threaded
worker processes equals the serial run, warm-start chains and all; a worker killed while it
trains a window loses no window and duplicates none."""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import fluidnerf
from conftest import TR_METHOD, TR_OPTIONS

distributed = pytest.importorskip("distributed")
import fluidnerf.dask  # noqa: E402


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=logging.ERROR
    )
    with distributed.Client(cluster) as c:
        yield c
    cluster.close()


@pytest.fixture(scope="module")
def serial(tr_scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / "run"
    return fluidnerf.reconstruct(tr_scene, TR_METHOD, out, progress=False, **TR_OPTIONS)


def assert_same_run(a: fluidnerf.Run, b: fluidnerf.Run) -> None:
    va, vb = a.volumes(), b.volumes()
    assert [t for t, _ in va] == [t for t, _ in vb] == [14.0, 14.5, 15.0, 15.5, 16.0]
    for (_, x), (_, y) in zip(va, vb):
        np.testing.assert_array_equal(x, y)
    ra, rb = a.report, b.report
    assert len(ra["windows"]) == len(rb["windows"]) == 4
    assert ra["history"]["loss"] == rb["history"]["loss"]
    assert [w["frames"] for w in rb["windows"]] == [[0, 2], [1, 3], [2, 4], [3, 5]]
    assert (a.path / "volumes.pvd").read_text() == (b.path / "volumes.pvd").read_text()


def test_a_time_resolved_field_is_sampled_only_between_its_instants(serial):
    points = np.zeros((2, 3), dtype=np.float32)
    np.testing.assert_array_equal(serial.field(points), serial.field(points, time=14.0))
    with pytest.raises(fluidnerf.FluidNerfError, match="outside the time-resolved run's instants 14"):
        serial.field(points, time=17.0)
    with pytest.raises(fluidnerf.FluidNerfError, match="finite"):
        serial.field(points, time=float("nan"))


def test_the_plan_is_the_one_tr_fast_uses(tr_scene):
    plan = fluidnerf.window_plan(tr_scene, TR_METHOD, **TR_OPTIONS)
    assert (
        plan["windows"]
        == [list(w) for w in fluidnerf.plan_windows(5, 2, 1)]
        == [[0, 2], [1, 3], [2, 4], [3, 5]]
    )
    assert plan["warm_start"] is True and plan["frame_times"] == [14.0, 14.5, 15.0, 15.5, 16.0]


def test_an_error_in_a_task_reaches_the_caller_as_a_fluidnerf_error(client, tmp_path):
    """FluidNerfError was named _fluidnerf.FluidNerfError, in no module Python can import: it
    could not be pickled, and an error raised in a task reached the client as another class,
    which `except fluidnerf.FluidNerfError` did not catch."""
    import pickle

    again = pickle.loads(pickle.dumps(fluidnerf.FluidNerfError("refused")))
    assert type(again) is fluidnerf.FluidNerfError and str(again) == "refused"
    future = client.submit(fluidnerf.load_scene, str(tmp_path / "nowhere"))
    with pytest.raises(fluidnerf.FluidNerfError, match="nowhere"):
        future.result()


def test_a_plan_of_more_than_a_million_windows_is_refused():
    assert len(fluidnerf.plan_windows(2_000_000, 2, 0)) == 1_000_000
    with pytest.raises(fluidnerf.FluidNerfError, match="make 1000001 windows"):
        fluidnerf.plan_windows(2_000_001, 2, 0)
    # Refused from its count, before any window is listed.
    with pytest.raises(fluidnerf.FluidNerfError, match="make 999999999999 windows"):
        fluidnerf.plan_windows(10**12, 2, 1)


def test_window_settings_the_command_line_refuses_are_refused(client, tr_scene, tmp_path):
    """An overlap given for windows that hold every frame (or for one field on every frame) was
    accepted from Python and Dask, recorded and ignored; a window shorter than the preset's
    overlap was refused without naming where the overlap came from. They are refused as
    --window and --overlap are, before anything is written."""
    one_window = {"name": "tr-fast", "windows": {"frames": 5, "overlap": 2}}
    said = (
        "method.windows.overlap 2: windows of 5 frames hold all 5 training frames of the scene in one window, "
        "so there are no windows to overlap; give method.windows.frames below 5 with it"
    )
    one_field = {"name": "tr-fast", "windows": {"frames": 0, "overlap": 1}}
    no_windows = "method.windows.overlap 1: the run trains one field on every frame (windows of 0 frames)"
    short = {"name": "tr-fast", "windows": {"frames": 3}}
    preset = (
        "method.windows.overlap: windows of 3 frames would overlap by 4 frames (the preset's overlap, as "
        "method.windows.overlap is not given)"
    )
    for method, words in [(one_window, said), (one_field, no_windows), (short, preset)]:
        with pytest.raises(fluidnerf.FluidNerfError, match=re.escape(words)):
            fluidnerf.window_plan(tr_scene, method)
        with pytest.raises(fluidnerf.FluidNerfError, match=re.escape(words)):
            fluidnerf.reconstruct(tr_scene, method, tmp_path / "serial", progress=False, **TR_OPTIONS)
        with pytest.raises(fluidnerf.FluidNerfError, match=re.escape(words)):
            fluidnerf.dask.reconstruct(client, tr_scene, method, tmp_path / "dask", **TR_OPTIONS)
        assert not (tmp_path / "serial").exists() and not (tmp_path / "dask").exists()
    # NumPy integers are counts as Python's are: they slipped past the check, recorded and ignored.
    for frames, overlap, words in [(5, 2, said), (0, 1, no_windows)]:
        numpy_counts = {
            "name": "tr-fast",
            "windows": {"frames": np.int64(frames), "overlap": np.int32(overlap)},
        }
        with pytest.raises(fluidnerf.FluidNerfError, match=re.escape(words)):
            fluidnerf.window_plan(tr_scene, numpy_counts)
    # Windows that overlap, and the preset's own settings, pass.
    overlapping = {"name": "tr-fast", "windows": {"frames": 4, "overlap": 2}}
    assert fluidnerf.window_plan(tr_scene, overlapping)["windows"] == [[0, 4], [1, 5]]
    assert fluidnerf.window_plan(tr_scene, "tr-fast")["windows"] == [[0, 5]]
    # An overlap of 0, which asks for nothing to overlap, is taken with one field on every frame.
    no_overlap = {"name": "tr-fast", "windows": {"frames": 0, "overlap": 0}}
    assert fluidnerf.window_plan(tr_scene, no_overlap)["windows"] == [[0, 5]]


def test_a_dask_run_equals_the_serial_run(client, tr_scene, serial, tmp_path):
    seen = []
    run = fluidnerf.dask.reconstruct(
        client, tr_scene, TR_METHOD, tmp_path / "run", callback=seen.append, **TR_OPTIONS
    )
    assert_same_run(serial, run)
    assert sorted(e["window"] for e in seen) == [0, 1, 2, 3] and not any(e["reused"] for e in seen)
    # Independent windows (no warm start) run in parallel and still equal their serial run.
    cold = {**TR_METHOD, "windows": {**TR_METHOD["windows"], "warm_start": False}}
    serial_cold = fluidnerf.reconstruct(
        tr_scene, cold, tmp_path / "serial-cold", progress=False, **TR_OPTIONS
    )
    assert_same_run(
        serial_cold, fluidnerf.dask.reconstruct(client, tr_scene, cold, tmp_path / "cold", **TR_OPTIONS)
    )


def kill_when_training(lock: Path, marker: Path, stop: threading.Event) -> None:
    """Kills the worker process that holds `lock` (a window's lock file holds its process id,
    then its machine's name), once, and records it in `marker`."""
    while not stop.is_set():
        try:
            pid = int(lock.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            time.sleep(0.002)
            continue
        marker.write_text(f"{pid}\n")
        os.kill(pid, signal.SIGKILL)
        return


def test_a_killed_worker_loses_and_duplicates_no_window(client, tr_scene, serial, tmp_path):
    out = tmp_path / "run"
    marker = tmp_path / "killed"
    stop = threading.Event()
    killer = threading.Thread(target=kill_when_training, args=(out / "windows" / "w002.lock", marker, stop))
    killer.start()
    seen = []
    try:
        run = fluidnerf.dask.reconstruct(client, tr_scene, TR_METHOD, out, callback=seen.append, **TR_OPTIONS)
    finally:
        stop.set()
        killer.join()
    assert marker.is_file(), "the worker training window 2 was killed"
    assert_same_run(serial, run)
    # Every window reported once; each has one done file and one checkpoint.
    assert sorted(e["window"] for e in seen) == [0, 1, 2, 3]
    files = sorted(p.name for p in (out / "windows").iterdir())
    assert [f for f in files if f.endswith(".done.json")] == [f"w{k:03d}.done.json" for k in range(4)]
    assert [f for f in files if f.endswith(".checkpoint.safetensors")] == [
        f"w{k:03d}.checkpoint.safetensors" for k in range(4)
    ]
    assert not [f for f in files if f.endswith(".lock") or f.endswith(".tmp")]
    assert json.loads((out / "windows" / "w002.done.json").read_text())["report"]["iterations"] == 8

    # Run again on the finished windows: every window is read back, and the results written again equal.
    again = fluidnerf.dask.reconstruct(client, tr_scene, TR_METHOD, tmp_path / "again", **TR_OPTIONS)
    assert_same_run(run, again)


def test_a_callback_that_cannot_be_called_is_refused_before_any_task(tr_scene, tmp_path):
    """callback=3 failed only when the first window finished, after the windows were trained."""
    with pytest.raises(TypeError, match="callback: expected a function of one event dict, got 3"):
        fluidnerf.dask.reconstruct(None, tr_scene, TR_METHOD, tmp_path / "run", callback=3, **TR_OPTIONS)
    assert not (tmp_path / "run").exists()


def test_a_client_that_is_no_dask_client_is_refused_before_anything_is_written(tr_scene, tmp_path):
    """client=None raised "AttributeError: 'NoneType' object has no attribute 'submit'" at
    the first task, after a scene built from arrays was saved into the run folder, and left
    there."""
    K, poses, _, _ = tr_scene.camera_arrays()
    times = np.array(tr_scene.times, dtype=np.float64)
    scene = fluidnerf.scene_from_arrays(K, poses, tr_scene.images(), tr_scene.aabb, times=times)
    for client in (None, "tcp://127.0.0.1:8786"):
        with pytest.raises(TypeError, match=r"^client: expected a Dask client \(distributed.Client\)"):
            fluidnerf.dask.reconstruct(client, scene, TR_METHOD, tmp_path / "run", **TR_OPTIONS)
        assert not (tmp_path / "run").exists()
        assert scene.root is None


def test_a_plan_of_negative_or_fractional_counts_is_refused_naming_the_argument():
    """A negative count raised pyo3's "OverflowError: can't convert negative int to unsigned",
    naming no argument, and window=True planned windows of one frame."""
    for args, name in [((-1, 2, 0), "n_frames"), ((5, -2, 0), "window"), ((5, 2, -1), "overlap")]:
        with pytest.raises(fluidnerf.FluidNerfError, match=rf"{name}: must be at least 0, got -"):
            fluidnerf.plan_windows(*args)
    with pytest.raises(TypeError, match="window: expected an integer, got True"):
        fluidnerf.plan_windows(5, True, 0)
    with pytest.raises(TypeError, match="n_frames: expected an integer, got 5.0"):
        fluidnerf.plan_windows(5.0, 2, 0)


def test_an_overlap_with_a_single_window_is_refused_as_a_run_refuses_it():
    """plan_windows(5, 0, 1) and (3, 5, 2) returned one window and dropped the overlap, where a
    run given the same window and overlap is refused."""
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"^overlap: 1 frames, but windows of 0 frames are one"
    ):
        fluidnerf.plan_windows(5, 0, 1)
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"^overlap: 2 frames, but windows of 5 frames hold all 3"
    ):
        fluidnerf.plan_windows(3, 5, 2)
    assert fluidnerf.plan_windows(5, 0, 0) == [(0, 5)] and fluidnerf.plan_windows(3, 5, 0) == [(0, 3)]


def test_a_plan_of_counts_beyond_64_bits_is_refused_naming_the_argument():
    """plan_windows(2**64, 2, 0) raised pyo3's bare "OverflowError: int too big to convert"."""
    for args, name in [((2**64, 2, 0), "n_frames"), ((5, 2**64, 0), "window"), ((5, 2, 2**70), "overlap")]:
        value = max(args)
        with pytest.raises(
            fluidnerf.FluidNerfError, match=rf"{name}: {value} is more than the largest count, 2\^64 - 1"
        ):
            fluidnerf.plan_windows(*args)
    assert fluidnerf.plan_windows(5, 2**64 - 1, 0) == [(0, 5)]


def test_a_window_index_outside_the_plan_is_refused_naming_the_argument_and_the_range(tr_scene, tmp_path):
    """train_window(window=-1) raised pyo3's bare "OverflowError: can't convert negative int to
    unsigned", and window=True trained window 1."""
    cfg = json.dumps(fluidnerf.build_config(tr_scene, TR_METHOD, **TR_OPTIONS))
    out = tmp_path / "run"
    for window in (-1, 4, 2**64 - 1, -(2**70)):
        with pytest.raises(
            fluidnerf.FluidNerfError,
            match=rf"window: {window} is not in the plan: the run has 4 window\(s\), 0 to 3",
        ):
            fluidnerf.dask.train_window(str(tr_scene.root), cfg, str(out), window)
    for window in (True, 1.0):
        with pytest.raises(TypeError, match=rf"window: expected an integer, got {window}"):
            fluidnerf.dask.train_window(str(tr_scene.root), cfg, str(out), window)
    assert not out.exists()


def test_windows_are_trained_only_on_the_scene_their_configuration_names(tr_scene, tmp_path):
    """train_window(scene_root, config) trained on scene_root while the run's config.json
    recorded the configuration's scene: windows of two scenes could be stitched into one run."""
    cfg = json.dumps(fluidnerf.build_config(tr_scene, TR_METHOD, **TR_OPTIONS))
    out = tmp_path / "run"
    # Another scene with frame times (one without has no windows to plan).
    other = tmp_path / "other"
    fluidnerf.load_scene(tr_scene.root).save(other)
    named = "scene: the configuration names the scene " + re.escape(
        f"{tr_scene.root}/transforms.json, not the one"
    )
    with pytest.raises(fluidnerf.FluidNerfError, match=named):
        fluidnerf.dask.train_window(str(other), cfg, str(out), 0)
    assert not out.exists()
    with pytest.raises(fluidnerf.FluidNerfError, match=named):
        fluidnerf.dask.finish(str(other), cfg, str(out))
    assert not out.exists()
    # The scene's file, or its folder by another spelling, is the same scene.
    same = json.loads(cfg) | {"scene": str(tr_scene.root / "." / "transforms.json")}
    outcome = fluidnerf.dask.train_window(str(tr_scene.root), json.dumps(same), str(out), 0)
    assert outcome["index"] == 0 and outcome["status"] == "finished"


def test_finishing_a_folder_without_trained_windows_says_to_train_them_first(tr_scene, tmp_path):
    """finish on a folder with no window trained said "nothing to resume (--resume;
    `overwrite="resume"` from Python): it holds no run", options the caller never used."""
    cfg = json.dumps(fluidnerf.build_config(tr_scene, TR_METHOD, **TR_OPTIONS))
    (tmp_path / "empty").mkdir()
    for out in (tmp_path / "run", tmp_path / "empty"):
        with pytest.raises(fluidnerf.FluidNerfError) as refused:
            fluidnerf.dask.finish(str(tr_scene.root), cfg, str(out))
        message = str(refused.value)
        assert message.startswith(f"{out}: no window of the run has been trained in this folder yet"), message
        assert "train its windows first (fluidnerf.dask.train_window" in message, message
        assert "resume" not in message, message
    assert not (tmp_path / "run").exists() and not any((tmp_path / "empty").iterdir())
    # A folder refused for its place is refused as before.
    (tmp_path / "file").write_text("x")
    with pytest.raises(fluidnerf.FluidNerfError, match="file: exists and is not a folder"):
        fluidnerf.dask.finish(str(tr_scene.root), cfg, str(tmp_path / "file"))
    with pytest.raises(fluidnerf.FluidNerfError, match="is the scene's own folder"):
        fluidnerf.dask.finish(str(tr_scene.root), cfg, str(tr_scene.root))


def test_a_refused_dask_run_of_a_scene_from_arrays_leaves_its_folder_as_it_was(
    tr_scene, static_scene, serial, tmp_path
):
    """A scene from arrays was saved into out/scene before the folder was checked: a run
    refused because the folder held a finished run left a scene inside that run's folder."""
    before = sorted(p.name for p in serial.path.iterdir())
    K, poses, _, _ = tr_scene.camera_arrays()
    times = np.array(tr_scene.times, dtype=np.float64)
    scene = fluidnerf.scene_from_arrays(K, poses, tr_scene.images(), tr_scene.aabb, times=times)
    # No client is used: the refusal comes before any task.
    with pytest.raises(fluidnerf.FluidNerfError, match="already holds a finished run"):
        fluidnerf.dask.reconstruct(None, scene, TR_METHOD, serial.path, **TR_OPTIONS)
    K, poses, _, _ = static_scene.camera_arrays()
    still = fluidnerf.scene_from_arrays(K, poses, static_scene.images(), static_scene.aabb)
    with pytest.raises(fluidnerf.FluidNerfError, match="already holds a finished run"):
        fluidnerf.dask.reconstruct(None, still, "asart", serial.path, resolution=8)
    assert sorted(p.name for p in serial.path.iterdir()) == before
    (tmp_path / "file").write_text("x")
    with pytest.raises(fluidnerf.FluidNerfError, match="file: exists and is not a folder"):
        fluidnerf.dask.reconstruct(None, scene, TR_METHOD, tmp_path / "file", **TR_OPTIONS)


def test_a_dask_run_without_a_method_runs_the_method_of_its_configuration(client, static_scene, tmp_path):
    """method defaulted to "tr-fast", unlike fluidnerf.reconstruct: a configuration of another
    method was refused ("written for method asart; to run method tr-fast, leave out config"),
    and a static scene given no method was refused for having no frame times."""
    cfg = fluidnerf.build_config(static_scene, "asart", resolution=8, stopping={"max_iterations": 3})
    run = fluidnerf.dask.reconstruct(client, static_scene, out=tmp_path / "run", config=cfg)
    assert run.report["method"] == "asart" and run.status == "finished" and run.volume.shape == (8, 8, 8)
    serial = fluidnerf.reconstruct(static_scene, out=tmp_path / "serial", config=cfg, progress=False)
    np.testing.assert_array_equal(run.volume, serial.volume)
    assert fluidnerf.build_config(static_scene)["method"]["name"] == "hybrid"


def test_a_finished_static_dask_run_is_replaced_with_the_overwrite_its_refusal_names(
    client, static_scene, tr_scene, tmp_path
):
    """A second call on a static run's folder was refused saying `overwrite="force"`, which
    fluidnerf.dask.reconstruct did not take: it was refused as an unknown configuration key."""
    out = tmp_path / "run"
    fluidnerf.dask.reconstruct(client, static_scene, "asart", out, resolution=8)
    with pytest.raises(fluidnerf.FluidNerfError, match='already holds a finished run.*overwrite="force"'):
        fluidnerf.dask.reconstruct(client, static_scene, "asart", out, resolution=10)
    run = fluidnerf.dask.reconstruct(client, static_scene, "asart", out, resolution=10, overwrite="force")
    assert run.status == "finished" and run.volume.shape == (10, 10, 10)
    with pytest.raises(fluidnerf.FluidNerfError, match="overwrite: expected 'refuse', 'force' or 'resume'"):
        fluidnerf.dask.reconstruct(None, static_scene, "asart", out, overwrite="yes")
    # A time-resolved run continues its windows when called again, and is never replaced.
    with pytest.raises(fluidnerf.FluidNerfError, match="overwrite: a time-resolved run on Dask continues"):
        fluidnerf.dask.reconstruct(
            None, tr_scene, TR_METHOD, tmp_path / "tr", overwrite="force", **TR_OPTIONS
        )
    assert not (tmp_path / "tr").exists()


def test_the_output_folder_of_a_scene_on_disk_is_refused_before_any_task(
    tr_scene, static_scene, serial, tmp_path
):
    """With a scene already saved, the output folder was not checked before the tasks were
    submitted: an output that is a file, or a finished run, was refused only by the workers."""
    (tmp_path / "file").write_text("x")
    # No client is used: the refusal comes before any task.
    for scene, method, options in [
        (tr_scene, TR_METHOD, TR_OPTIONS),
        (static_scene, "asart", {"resolution": 8}),
    ]:
        with pytest.raises(fluidnerf.FluidNerfError, match="file: exists and is not a folder"):
            fluidnerf.dask.reconstruct(None, scene, method, tmp_path / "file", **options)
        with pytest.raises(fluidnerf.FluidNerfError, match="already holds a finished run"):
            fluidnerf.dask.reconstruct(None, scene, method, serial.path, **options)
    assert (tmp_path / "file").read_text() == "x"


def test_a_scene_from_arrays_built_again_continues_its_dask_run_and_another_is_refused(tr_scene, tmp_path):
    """Called again after an interruption, with the scene built again from its arrays, a
    scale-out was refused ("pass force=True"): the first call had saved it in out/scene. The
    same arrays now continue the run; other arrays are refused and the saved scene kept."""

    class Stop(Exception):
        pass

    class Submits:
        """A client that records the first task of each call and stops the call there."""

        def __init__(self) -> None:
            self.keys: list[str] = []

        def submit(self, *args, key: str, **kwargs):
            self.keys.append(key)
            raise Stop

    K, poses, _, _ = tr_scene.camera_arrays()
    times = np.array(tr_scene.times, dtype=np.float64)
    images = np.asarray(tr_scene.images())
    out = tmp_path / "run"

    def build(pixels: np.ndarray) -> fluidnerf.Scene:
        return fluidnerf.scene_from_arrays(K, poses, pixels, tr_scene.aabb, times=times)

    client = Submits()
    with pytest.raises(Stop):
        fluidnerf.dask.reconstruct(client, build(images), TR_METHOD, out, **TR_OPTIONS)
    with pytest.raises(Stop):
        fluidnerf.dask.reconstruct(client, build(images), TR_METHOD, out, **TR_OPTIONS)
    assert [k.startswith("fluidnerf-window-000-") for k in client.keys] == [True, True]
    saved = out / "scene" / "transforms.json"
    stamp = saved.stat().st_mtime_ns
    with pytest.raises(fluidnerf.FluidNerfError, match="differs from it"):
        fluidnerf.dask.reconstruct(client, build(images * 2), TR_METHOD, out, **TR_OPTIONS)
    assert len(client.keys) == 2 and saved.stat().st_mtime_ns == stamp


def test_a_scale_out_refused_before_it_wrote_takes_back_the_scene_it_saved(tr_scene, tmp_path):
    """A scene from arrays saved into out/scene stayed there when the run was refused after
    that (a worker's refusal before the run wrote anything): the same call, corrected, then had
    to match a scene the caller never meant to keep. It is taken back, as ``reconstruct`` does;
    a call stopped otherwise keeps it, so that it can continue."""

    class Refuses:
        """A client whose first task is refused, as a worker refuses a run it cannot do."""

        def submit(self, *args, key: str, **kwargs):
            raise fluidnerf.FluidNerfError("refused by the worker")

    K, poses, _, _ = tr_scene.camera_arrays()
    times = np.array(tr_scene.times, dtype=np.float64)
    scene = fluidnerf.scene_from_arrays(K, poses, tr_scene.images(), tr_scene.aabb, times=times)
    out = tmp_path / "run"
    with pytest.raises(fluidnerf.FluidNerfError, match="refused by the worker"):
        fluidnerf.dask.reconstruct(Refuses(), scene, TR_METHOD, out, **TR_OPTIONS)
    assert not out.exists() and scene.root is None
    # A folder the caller made stays; only what the call saved goes.
    out.mkdir()
    with pytest.raises(fluidnerf.FluidNerfError, match="refused by the worker"):
        fluidnerf.dask.reconstruct(Refuses(), scene, TR_METHOD, out, **TR_OPTIONS)
    assert out.is_dir() and not any(out.iterdir()) and scene.root is None


def test_windows_near_the_largest_count_are_planned():
    """A window near 2^64 frames overflowed the plan's frame arithmetic, which then listed
    windows until the memory ran out."""
    n = 2**64 - 1
    assert fluidnerf.plan_windows(n, n - 1, 1) == [(0, n - 1), (1, n)]


def test_task_arguments_of_another_type_are_refused_naming_the_argument(tr_scene, tmp_path):
    """train_window(None, ...) was refused naming `folder`, Scene.load's argument, and a
    configuration that is no string as pyo3 names a string's type."""
    cfg = json.dumps(fluidnerf.build_config(tr_scene, TR_METHOD, **TR_OPTIONS))
    root, out = str(tr_scene.root), str(tmp_path / "run")
    for args, says in (
        ((None, cfg, out), r"^scene_root: expected a path \(a string or os.PathLike\), got NoneType None"),
        ((root, 5, out), r"^config_json: expected a string, got int 5"),
        ((root, cfg, None), r"^out: expected a path \(a string or os.PathLike\), got NoneType None"),
    ):
        with pytest.raises(TypeError, match=says):
            fluidnerf.dask.train_window(*args, 0)
        with pytest.raises(TypeError, match=says):
            fluidnerf.dask.finish(*args)
    assert not (tmp_path / "run").exists()


def test_a_window_trained_twice_at_once_is_trained_once_and_read_back(tr_scene, tmp_path):
    """A second task of a window that another task was still training (a task Dask ran again
    while the first still worked) failed the run as "in use by another run" instead of taking
    the finished window."""
    cfg = json.dumps(fluidnerf.build_config(tr_scene, TR_METHOD, **TR_OPTIONS))
    root, out = str(tr_scene.root), str(tmp_path / "run")
    outcomes, errors = [], []

    def task():
        try:
            outcomes.append(fluidnerf.dask.train_window(root, cfg, out, 0))
        except Exception as e:  # noqa: BLE001 - reported below
            errors.append(e)

    threads = [threading.Thread(target=task) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors, errors
    assert sorted(o["reused"] for o in outcomes) == [False, True]
    assert outcomes[0]["final_loss"] == outcomes[1]["final_loss"]


def test_an_overlap_of_a_single_frame_or_none_is_refused_without_a_window_to_give():
    """plan_windows(1, 4, 1) advised "give a window below 1", and (0, 4, 1) "a window below 0":
    no window makes an overlap of one frame or none."""
    for n in (0, 1):
        with pytest.raises(fluidnerf.FluidNerfError, match=None) as e:
            fluidnerf.plan_windows(n, 4, 1)
        assert str(e.value) == (
            f"overlap: 1 frames, but {n} frame(s) make one window at most, so there are no windows to overlap; "
            "give an overlap of 0"
        )
    assert fluidnerf.plan_windows(1, 4, 0) == [(0, 1)]


def test_the_warnings_of_a_dask_run_are_issued_on_the_client(client, tr_scene, tmp_path):
    """A run's warnings were issued on the workers, where nobody sees them: fluidnerf.reconstruct
    warned that a voxel method mixes the scene's times, fluidnerf.dask.reconstruct said nothing;
    a window's task returned none of its warnings to the client."""
    with pytest.warns(fluidnerf.FluidNerfWarning, match=None) as caught:
        run = fluidnerf.dask.reconstruct(
            client, tr_scene, "asart", tmp_path / "run", resolution=4, stopping={"max_iterations": 1}
        )
    said = [str(w.message) for w in caught if issubclass(w.category, fluidnerf.FluidNerfWarning)]
    assert len(said) == 1 and said[0].startswith(
        "the scene has 5 time steps; a voxel reconstruction mixes"
    ), said
    assert run.report["warnings"] == said
    # A window's task returns its warnings, which the client issues as the window finishes.
    method = {**TR_METHOD, "windows": {"frames": 0}, "holdout_times": [14.25]}
    cfg = fluidnerf.build_config(tr_scene, method, **{**TR_OPTIONS, "stopping": {"max_iterations": 1}})
    outcome = fluidnerf.dask.train_window(str(tr_scene.root), json.dumps(cfg), str(tmp_path / "windows"), 0)
    assert [w[:40] for w in outcome["warnings"]] == ["held-out time 14.25 matches no frame of "]


def _lock_of_another_machine(path: Path, heartbeat: bool, age_s: float) -> None:
    """Writes the lock file `path` as a process of another machine holds it, refreshed by a
    heartbeat or not (an earlier fluidnerf's), last modified `age_s` seconds ago. Written anew
    (another file), as a lock taken over is."""
    path.unlink(missing_ok=True)
    path.write_text("4194305\nanother-machine.example\n" + ("heartbeat\n" if heartbeat else ""))
    t = time.time() - age_s
    os.utime(path, (t, t))


def _train_window_in_thread(args: tuple) -> tuple[threading.Thread, list, list]:
    outcomes: list = []
    errors: list = []

    def task() -> None:
        try:
            outcomes.append(fluidnerf.dask.train_window(*args))
        except Exception as e:  # noqa: BLE001 - reported by the caller
            errors.append(e)

    thread = threading.Thread(target=task, daemon=True)
    thread.start()
    return thread, outcomes, errors


def test_a_window_locked_by_a_machine_that_died_is_trained_once_its_heartbeat_stopped(tr_scene, tmp_path):
    """A window's lock left by a worker machine that died was held for ever: train_window
    waited for it for ever (and the command line refused it for ever)."""
    cfg = json.dumps(fluidnerf.build_config(tr_scene, TR_METHOD, **TR_OPTIONS))
    root, out = str(tr_scene.root), str(tmp_path / "run")
    fluidnerf.dask.train_window(root, cfg, out, 0)
    lock = tmp_path / "run" / "windows" / "w001.lock"
    _lock_of_another_machine(lock, heartbeat=True, age_s=600)
    thread, outcomes, errors = _train_window_in_thread((root, cfg, out, 1))
    thread.join(timeout=120)
    assert not thread.is_alive(), "train_window still waits for the lock of a machine that died"
    assert not errors, errors
    assert outcomes[0]["index"] == 1 and outcomes[0]["reused"] is False
    assert not lock.exists()


def test_a_window_lock_that_is_never_replaced_is_not_waited_for_and_the_wait_is_reported(tr_scene, tmp_path):
    """While another machine's heartbeat goes on its window is waited for; a lock of an
    earlier fluidnerf (no heartbeat), which is never taken as stale, ends the wait with an
    error saying how long it waited, instead of a wait for ever."""
    cfg = json.dumps(fluidnerf.build_config(tr_scene, TR_METHOD, **TR_OPTIONS))
    root, out = str(tr_scene.root), str(tmp_path / "run")
    fluidnerf.dask.train_window(root, cfg, out, 0)
    lock = tmp_path / "run" / "windows" / "w001.lock"
    _lock_of_another_machine(lock, heartbeat=True, age_s=0)
    thread, outcomes, errors = _train_window_in_thread((root, cfg, out, 1))
    thread.join(timeout=1.0)
    assert thread.is_alive() and not outcomes and not errors, "a live holder's window was not waited for"
    _lock_of_another_machine(lock, heartbeat=False, age_s=0)
    thread.join(timeout=60)
    assert not thread.is_alive(), "train_window still waits for a lock that is never replaced"
    assert not outcomes and len(errors) == 1
    message = str(errors[0])
    assert isinstance(errors[0], fluidnerf.FluidNerfError)
    assert re.search(
        r"^window 1: .*in use by another run \(process 4194305 on another-machine.example", message
    )
    assert "remove the lock file" in message
    assert re.search(
        r"after waiting \d+ s for another task that held its lock w001.lock, \d+ attempt", message
    )
    # Without a wait, the refusal is the pipeline's own.
    with pytest.raises(fluidnerf.FluidNerfError, match="remove the lock file") as e:
        fluidnerf.dask.train_window(root, cfg, out, 1)
    assert "after waiting" not in str(e.value)


def test_a_finished_time_resolved_dask_run_resumed_is_returned_as_the_serial_resume_returns_it(
    client, tr_scene, serial, tmp_path
):
    """overwrite="resume" on a folder holding a finished time-resolved run was refused ("already
    holds a finished run; training windows into it would mix two runs"), where
    fluidnerf.reconstruct and `reconstruct --resume` read its windows back and return the run."""
    out = tmp_path / "run"
    first = fluidnerf.dask.reconstruct(client, tr_scene, TR_METHOD, out, **TR_OPTIONS)
    done = {p.name: p.stat().st_mtime_ns for p in (out / "windows").glob("*.done.json")}
    assert len(done) == 4
    again = fluidnerf.dask.reconstruct(client, tr_scene, TR_METHOD, out, overwrite="resume", **TR_OPTIONS)
    assert again.status == "finished" and again.path == first.path
    assert_same_run(serial, again)
    assert {p.name: p.stat().st_mtime_ns for p in (out / "windows").glob("*.done.json")} == done, (
        "trained again"
    )
    # The serial path, the reference, on its own finished run.
    serial_out = tmp_path / "serial"
    fluidnerf.reconstruct(tr_scene, TR_METHOD, serial_out, progress=False, **TR_OPTIONS)
    resumed = fluidnerf.reconstruct(
        tr_scene, TR_METHOD, serial_out, overwrite="resume", progress=False, **TR_OPTIONS
    )
    assert resumed.status == again.status
    assert_same_run(resumed, again)
    # Without "resume" a finished run is still refused, as the serial path refuses it.
    with pytest.raises(fluidnerf.FluidNerfError, match="already holds a finished run"):
        fluidnerf.dask.reconstruct(client, tr_scene, TR_METHOD, out, **TR_OPTIONS)
