"""Runs from Python: the same pipeline and settings as the command line, bit for bit; the
trained field against the exported volume; settings refused with the library's messages;
callbacks that watch and stop a run."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import fluidnerf
from conftest import TR_METHOD, TR_OPTIONS

# The grid field with few rays and samples: a run of a second or two.
FAST_METHOD = {"name": "fast", "train": {"rays_per_image": 64, "coarse_samples": 16}}
FAST = {
    "resolution": 16,
    "seed": 3,
    "stopping": {"rule": "budget", "max_iterations": 20},
    "checkpoint_every": 0,
}


def test_a_hybrids_voxel_start_reports_its_events_and_stops_with_the_callback(static_scene, tmp_path):
    """The hybrid's voxel start reports its own run before the field's, and a callback that
    stops there stops the start and the run. Its events were dropped: a callback could not
    stop it, and a progress bar showed nothing while it ran."""
    events = []
    short = {
        "resolution": 16,
        "seed": 3,
        "stopping": {"rule": "budget", "max_iterations": 3},
        "checkpoint_every": 0,
    }
    run = fluidnerf.reconstruct(static_scene, "hybrid", tmp_path / "h", callback=events.append, **short)
    assert run.status == "finished"
    started = [e["method"] for e in events if e["kind"] == "started"]
    assert started == ["asart", "hybrid"]
    kinds = [e["kind"] for e in events]
    assert kinds.index("writing") < kinds.index("start_fit") < kinds.index("started", 1)
    fit = [(e["step"], e["steps"]) for e in events if e["kind"] == "start_fit"]
    assert fit == [(s, 300) for s in range(10, 301, 10)]

    def stop_in_the_start(event: dict) -> bool:
        return not (event["kind"] == "iteration" and event["iteration"] == 2)

    # Stopped before the field trained: its volume is said to be the untrained field's.
    untrained = "before it trained: volume.npy is the field before training"
    with pytest.warns(fluidnerf.FluidNerfWarning, match=untrained):
        stopped = fluidnerf.reconstruct(
            static_scene, "hybrid", tmp_path / "s", callback=stop_in_the_start, **short
        )
    assert stopped.status == "interrupted"
    assert untrained in " ".join(stopped.report["warnings"])
    start = json.loads((tmp_path / "s" / "start" / "report.json").read_text())
    assert start["stop_reason"] == "interrupted" and start["iterations"] == 2

    # Stopped while the field is fitted to the start: the fit ends there, and the run after
    # its first iteration.
    def stop_in_the_fit(event: dict) -> bool:
        return not (event["kind"] == "start_fit" and event["step"] == 20)

    fitted = []
    with pytest.warns(fluidnerf.FluidNerfWarning, match=untrained):
        stopped = fluidnerf.reconstruct(
            static_scene,
            "hybrid",
            tmp_path / "f",
            callback=lambda e: (fitted.append(e), stop_in_the_fit(e))[1],
            **short,
        )
    assert stopped.status == "interrupted" and stopped.report["iterations"] <= 1
    assert [e["step"] for e in fitted if e["kind"] == "start_fit"] == [10, 20]


def test_a_python_run_equals_the_command_line_run_and_its_field_the_volume(static_scene, cli, tmp_path):
    events = []
    run = fluidnerf.reconstruct(static_scene, FAST_METHOD, tmp_path / "py", callback=events.append, **FAST)
    assert run.kind == "field" and run.status == "finished"
    assert run.volume.shape == (16, 16, 16) and run.volume.dtype == np.float32
    report = run.report
    assert report["method"] == "fast" and report["iterations"] == 20
    assert run.config["seed"] == 3 and run.config["method"]["train"]["rays_per_image"] == 64
    kinds = [e["kind"] for e in events]
    assert kinds[0] == "started" and kinds.count("iteration") == 20 and "writing" in kinds
    assert [e["iteration"] for e in events if e["kind"] == "iteration"] == list(range(1, 21))

    # The command line, rerunning the saved settings, writes the same volume bit for bit.
    out = subprocess.run(
        [cli, "reconstruct", "--config", str(run.path / "config.json"), "-o", str(tmp_path / "cli"), "-q"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    cli_run = fluidnerf.open_run(tmp_path / "cli")
    np.testing.assert_array_equal(cli_run.volume, run.volume)
    assert cli_run.report["history"]["loss"] == report["history"]["loss"]

    # The trained field at the voxel centres is the exported volume.
    centres = run.voxel_centres().reshape(-1, 3)
    values = run.field(centres).reshape(run.volume.shape)
    np.testing.assert_allclose(values, run.volume, rtol=1e-5, atol=1e-6 * float(np.abs(run.volume).max()))
    # Outside the box the field is zero.
    assert (run.field(np.array([[1e3, 0.0, 0.0], [0.0, -1e3, 0.0]])) == 0).all()
    with pytest.raises(fluidnerf.FluidNerfError, match=r"points: expected shape \(N, 3\)"):
        run.field(np.zeros((4, 2)))
    # A static field is the same at every time; a time given to it is warned of.
    with pytest.warns(fluidnerf.FluidNerfWarning, match="time=3.0 has no effect"):
        at_three = run.field(centres[:5], time=3.0)
    np.testing.assert_array_equal(at_three, run.field(centres[:5]))
    # A time that is no finite number is refused, and not first warned of as unused.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(TypeError, match="time: expected a number, got '1'"):
            run.field(centres[:5], time="1")
        with pytest.raises(fluidnerf.FluidNerfError, match="time: expected a finite number"):
            run.field(centres[:5], time=float("nan"))

    copy = run.save(tmp_path / "copy")
    np.testing.assert_array_equal(copy.volume, run.volume)
    # Not into a folder that exists, its own or another run's, nor inside its own folder (a copy
    # there was left among the run's files, and copied again with every later copy).
    for folder in (run.path, copy.path):
        with pytest.raises(fluidnerf.FluidNerfError, match="already exists; choose a new folder"):
            run.save(folder)
    before = sorted(p.name for p in run.path.iterdir())
    with pytest.raises(fluidnerf.FluidNerfError, match="lies inside the run's own folder"):
        run.save(run.path / "copy")
    assert sorted(p.name for p in run.path.iterdir()) == before


def test_a_run_is_not_saved_under_a_file(static_scene, tmp_path):
    """run.save("a_file/sub") raised a bare NotADirectoryError from the copy."""
    run = fluidnerf.reconstruct(static_scene, "asart", tmp_path / "run", resolution=8, progress=False)
    (tmp_path / "a_file").write_text("x")
    for folder in (tmp_path / "a_file" / "sub", tmp_path / "a_file" / "sub" / "deeper"):
        with pytest.raises(
            fluidnerf.FluidNerfError,
            match=re.escape(f"{folder}: cannot create the folder, {tmp_path / 'a_file'} is a file"),
        ):
            run.save(folder)
    assert (tmp_path / "a_file").read_text() == "x"


def test_a_scene_changed_on_disk_after_it_was_loaded_is_refused(static_scene, tmp_path):
    """A Scene edited on disk after it was loaded was reconstructed from the old box while the
    run's config.json named the folder, whose new box a rerun then read. Its run is refused;
    loaded again, it runs."""
    folder = tmp_path / "scene"
    shutil.copytree(static_scene.root, folder)
    loaded = fluidnerf.load_scene(folder)
    transforms = json.loads((folder / "transforms.json").read_text())
    transforms["aabb"] = [[-10.0, -10.0, -10.0], [10.0, 10.0, 10.0]]
    (folder / "transforms.json").write_text(json.dumps(transforms))
    with pytest.raises(fluidnerf.FluidNerfError, match="has changed on disk since this Scene was loaded"):
        fluidnerf.reconstruct(loaded, "asart", tmp_path / "run", resolution=8, progress=False)
    assert not (tmp_path / "run").exists()
    again = fluidnerf.reconstruct(
        fluidnerf.load_scene(folder), "asart", tmp_path / "run", resolution=8, progress=False
    )
    assert again.status == "finished"


def test_a_run_whose_files_changed_after_it_was_opened_is_refused(static_scene, tmp_path):
    """A Run kept the field it had loaded while its volume was read anew from the disk: after
    volume.npy was replaced, field() and volume gave two different results without a word."""
    fluidnerf.reconstruct(static_scene, "asart", tmp_path / "run", resolution=8, progress=False)
    run = fluidnerf.open_run(tmp_path / "run")
    before = run.field(np.zeros((1, 3), np.float32))
    np.save(tmp_path / "run" / "volume.npy", np.full((8, 8, 8), 7.0, np.float32))
    for call in (lambda: run.field(np.zeros((1, 3), np.float32)), lambda: run.volume):
        with pytest.raises(
            fluidnerf.FluidNerfError, match="volume.npy has changed on disk since the run was opened"
        ):
            call()
    reopened = fluidnerf.open_run(tmp_path / "run")
    assert reopened.field(np.zeros((1, 3), np.float32))[0] == pytest.approx(7.0)
    assert before[0] != pytest.approx(7.0)


def test_a_runs_kept_volume_report_and_settings_are_refused_once_the_run_is_replaced(static_scene, tmp_path):
    """A Run gave the volume it had kept, and the report and settings it had read, of a run
    that another had since replaced in its folder, while ``volumes()`` refused it: the old
    run's results were taken for the folder's. Each refuses it now, as ``volumes()`` does; the
    Run still says which folder it was."""
    options = {"stopping": {"max_iterations": 3}, "progress": False}
    fluidnerf.reconstruct(static_scene, "asart", tmp_path / "run", resolution=12, **options)
    run = fluidnerf.open_run(tmp_path / "run")
    assert (
        run.volume.shape == (12, 12, 12)
        and run.report["method"] == "asart"
        and run.config["resolution"] == 12
    )
    fluidnerf.reconstruct(static_scene, "sart", tmp_path / "run", resolution=8, overwrite="force", **options)
    changed = "volume.npy has changed on disk since the run was opened; open it again with fluidnerf.open_run"
    calls = [
        ("volume", lambda: run.volume),
        ("report", lambda: run.report),
        ("config", lambda: run.config),
        ("report", lambda: run.status),
        ("volume", run.voxel_centres),
        ("volumes", run.volumes),
    ]
    for what, call in calls:
        with pytest.raises(
            fluidnerf.FluidNerfError, match=re.escape(f"{what}: {tmp_path / 'run'}/{changed}")
        ):
            call()
    assert str(tmp_path / "run") in repr(run) and "changed on disk" in repr(run)
    reopened = fluidnerf.open_run(tmp_path / "run")
    assert reopened.volume.shape == (8, 8, 8) and reopened.report["method"] == "sart"


def test_a_run_that_cannot_be_copied_whole_leaves_no_half_copy(static_scene, tmp_path):
    """A file the copy could not read (here a link to nothing) raised a bare shutil.Error, and
    left the files copied before it at the destination, which a second attempt then refused as
    existing."""
    run = fluidnerf.reconstruct(static_scene, "asart", tmp_path / "run", resolution=8, progress=False)
    (run.path / "zz_link").symlink_to(tmp_path / "nothing")
    dest = tmp_path / "copies" / "copy"
    with pytest.raises(
        fluidnerf.FluidNerfError, match=re.escape(f"{dest}: cannot copy the run {run.path} there")
    ):
        run.save(dest)
    assert not (tmp_path / "copies").exists()
    (run.path / "zz_link").unlink()
    copy = run.save(dest)
    np.testing.assert_array_equal(copy.volume, run.volume)
    assert sorted(p.name for p in (tmp_path / "copies").iterdir()) == ["copy"]


def test_the_window_plan_of_a_scene_without_frame_times_is_refused(static_scene, tr_scene):
    """A scene none of whose frames has a time was planned as one window of one frame at
    t = 0, a time the scene does not have."""
    assert fluidnerf.window_plan(tr_scene, "tr-fast")["frame_times"] == [14.0, 14.5, 15.0, 15.5, 16.0]
    with pytest.raises(
        fluidnerf.FluidNerfError,
        match=re.escape(
            f"method: tr-fast plans its windows over the frames' times, and the scene {static_scene.root} has "
            "no frame times (no frame has a `time`); give every frame its time, or reconstruct the scene "
            "with a static method"
        ),
    ):
        fluidnerf.window_plan(static_scene, "tr-fast")


def test_a_voxel_run_and_its_truth_metrics(static_scene, tmp_path):
    run = fluidnerf.reconstruct(
        static_scene,
        "asart",
        tmp_path / "asart",
        resolution=20,
        stopping={"max_iterations": 8},
        progress=False,
    )
    assert run.kind == "volume" and run.report["iterations"] <= 8
    ((_, truth),) = static_scene.truth()
    # The report's NRMSE is the package's on the same arrays.
    assert fluidnerf.nrmse(run.volume, truth) == pytest.approx(run.report["final_nrmse"], rel=1e-9)
    # A voxel run's field samples its volume: at voxel centres it is the volume.
    c = run.voxel_centres().reshape(-1, 3)
    np.testing.assert_allclose(run.field(c).reshape(run.volume.shape), run.volume, rtol=1e-5, atol=1e-7)


def test_a_runs_warnings_are_issued_and_kept_in_its_report(static_scene, tmp_path):
    # SART-TV inside a visual hull with the data step rule warns that its weight then
    # over-smooths the hull's voxels.
    method = {"name": "tv", "projector": {"visual_hull": True}, "params": {"step_rule": "data"}}
    with pytest.warns(fluidnerf.FluidNerfWarning, match="SART-TV inside a visual hull") as caught:
        run = fluidnerf.reconstruct(
            static_scene,
            method,
            tmp_path / "tv",
            resolution=8,
            stopping={"max_iterations": 2},
            progress=False,
        )
    (warning,) = run.report["warnings"]
    assert warning.startswith("SART-TV inside a visual hull")
    # Issued at the caller's line, not at the package's callback, so that the location shown and
    # `filterwarnings(module=...)` say whose call it was.
    assert [w.filename for w in caught] == [__file__]
    # Without the hull, nothing to warn of.
    plain = fluidnerf.reconstruct(
        static_scene, "tv", tmp_path / "plain", resolution=8, stopping={"max_iterations": 2}, progress=False
    )
    assert plain.report["warnings"] == []


def test_a_saved_configuration_reruns_its_own_method(static_scene, tr_scene, tmp_path):
    first = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "a", resolution=8, stopping={"max_iterations": 2}, progress=False
    )
    # No method given: the configuration's, not the default's.
    again = fluidnerf.reconstruct(
        static_scene, config=first.path / "config.json", out=tmp_path / "b", progress=False
    )
    assert again.report["method"] == "asart"
    np.testing.assert_array_equal(again.volume, first.volume)
    # Neither given: the default method, as on the command line; tr-fast for several times.
    assert fluidnerf.build_config(static_scene)["method"]["name"] == "hybrid"
    assert fluidnerf.build_config(tr_scene)["method"]["name"] == "tr-fast"
    # A resumed run continues with its own settings, here to a higher cap.
    short = dict(FAST, stopping={"rule": "budget", "max_iterations": 5})
    fluidnerf.reconstruct(static_scene, FAST_METHOD, tmp_path / "r", progress=False, **short)
    more = fluidnerf.reconstruct(
        static_scene, out=tmp_path / "r", overwrite="resume", stopping={"max_iterations": 8}, progress=False
    )
    assert more.report["method"] == "fast" and more.report["iterations"] == 8
    assert more.config["method"]["train"]["rays_per_image"] == 64


def test_a_run_records_the_version_that_made_it_as_the_command_line_does(static_scene, cli, tmp_path):
    """A configuration of another version (an earlier run's, or a version given) kept its
    own: the new run's config.json named a version that did not write it, where the command
    line, given the same configuration, records its own."""
    cfg = fluidnerf.build_config(static_scene, "asart", resolution=8, stopping={"max_iterations": 2})
    assert cfg["fluidnerf_version"] == fluidnerf.__version__
    old = {**cfg, "fluidnerf_version": "0.0.1"}
    run = fluidnerf.reconstruct(static_scene, config=old, out=tmp_path / "py", progress=False)
    assert run.config["fluidnerf_version"] == fluidnerf.__version__
    written = json.loads((run.path / "config.json").read_text())
    (tmp_path / "old.json").write_text(json.dumps(old))
    subprocess.run(
        [cli, "reconstruct", "--config", str(tmp_path / "old.json"), "-o", str(tmp_path / "cli"), "-q"],
        check=True,
        capture_output=True,
    )
    assert written == json.loads((tmp_path / "cli" / "config.json").read_text())


def test_settings_are_refused_with_the_messages_of_the_command_line(static_scene, cli, tmp_path):
    with pytest.raises(fluidnerf.FluidNerfError) as e:
        fluidnerf.reconstruct(static_scene, "asart", tmp_path / "a", resolution=1)
    out = subprocess.run(
        [
            cli,
            "reconstruct",
            str(static_scene.root),
            "-o",
            str(tmp_path / "b"),
            "--method",
            "asart",
            "--resolution",
            "1",
        ],
        capture_output=True,
        text=True,
    )
    assert out.returncode != 0 and str(e.value) in out.stderr
    assert str(e.value) == "resolution: must be between 2 and 4096 voxels along the longest side, got 1"
    with pytest.raises(fluidnerf.FluidNerfError, match="at `sed`: unknown field `sed`"):
        fluidnerf.reconstruct(static_scene, "asart", tmp_path / "c", sed=1)
    with pytest.raises(fluidnerf.FluidNerfError, match="relaxaton"):
        fluidnerf.reconstruct(static_scene, {"name": "asart", "params": {"relaxaton": 0.3}}, tmp_path / "c")
    with pytest.raises(fluidnerf.FluidNerfError, match='unknown method "nerf"'):
        fluidnerf.reconstruct(static_scene, "nerf", tmp_path / "c")
    with pytest.raises(
        fluidnerf.FluidNerfError, match="stopping.max_iterations: must be 1 to 1000000000 iterations, got 0"
    ):
        fluidnerf.reconstruct(static_scene, FAST_METHOD, tmp_path / "c", stopping={"max_iterations": 0})
    # A folder holding a finished run is not overwritten without being asked.
    fluidnerf.reconstruct(static_scene, "asart", tmp_path / "d", resolution=8, stopping={"max_iterations": 1})
    with pytest.raises(fluidnerf.FluidNerfError, match='already holds a finished run.*overwrite="force"'):
        fluidnerf.reconstruct(static_scene, "asart", tmp_path / "d", resolution=8)
    fluidnerf.reconstruct(static_scene, "asart", tmp_path / "d", resolution=8, overwrite="force")


def test_an_integer_setting_beyond_64_bits_is_refused_as_the_integer_given(static_scene, tmp_path):
    """seed=2**64 was refused as "invalid type: floating point `1.8446744073709552e+19`,
    expected u64", an error about a float the caller never gave."""
    beyond = "is beyond the 64-bit integers settings hold"
    with pytest.raises(
        fluidnerf.FluidNerfError, match=f"configuration: at `seed`: 18446744073709551616 {beyond}"
    ):
        fluidnerf.build_config(static_scene, "asart", seed=2**64)
    with pytest.raises(
        fluidnerf.FluidNerfError, match=rf"configuration: at `stopping.max_iterations`: -{2**63 + 1} {beyond}"
    ):
        fluidnerf.build_config(static_scene, "asart", stopping={"max_iterations": -(2**63) - 1})
    with pytest.raises(fluidnerf.FluidNerfError, match=f"synth settings: at `seed`: {2**70} {beyond}"):
        fluidnerf.synth(tmp_path / "s", "demo", seed=2**70)
    assert not (tmp_path / "s").exists()
    assert fluidnerf.build_config(static_scene, "asart", seed=2**64 - 1)["seed"] == 2**64 - 1


def test_settings_given_as_numpy_numbers_or_not_finite_are_read_or_refused_by_key(static_scene, tmp_path):
    """NumPy numbers and arrays in settings raised "TypeError: Object of type int64 is not JSON
    serializable", and a NaN or an infinity "configuration: expected value at line 1 column
    482": neither named the key."""
    cfg = fluidnerf.build_config(
        static_scene, "asart", resolution=np.int64(8), stopping={"time_budget_s": np.float32(2.5)}
    )
    assert cfg["resolution"] == 8 and cfg["stopping"]["time_budget_s"] == 2.5
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"configuration: at `stopping.time_budget_s`: nan is not"
    ):
        fluidnerf.reconstruct(static_scene, "asart", tmp_path / "a", stopping={"time_budget_s": float("nan")})
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"configuration: at `method.params.relaxation`: inf is"
    ):
        fluidnerf.build_config(static_scene, {"name": "asart", "params": {"relaxation": np.inf}})
    with pytest.raises(TypeError, match=r"configuration: at `seed`: expected a number, .* got object"):
        fluidnerf.build_config(static_scene, "asart", seed=object())
    vol = np.ones((4, 4, 4), np.float32)
    assert (
        fluidnerf.forward_project(static_scene, vol, {"kind": "ray", "ray_step": np.float32(0.5)}).shape[0]
        == 8
    )
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"projector: at `ray_step`: nan is not a finite number"
    ):
        fluidnerf.forward_project(static_scene, vol, {"kind": "ray", "ray_step": float("nan")})
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"synth settings: at `lens.resolution\[1\]`: inf is not"
    ):
        fluidnerf.synth(tmp_path / "s", "demo", lens={"resolution": np.array([8.0, np.inf])})
    scene = fluidnerf.synth(
        tmp_path / "t",
        "demo",
        resolution=np.int64(8),
        lens={"resolution": np.array([8, 8])},
        rig={"layout": {"count": 3}},
    )
    assert len(scene) == 3


def test_a_configuration_or_method_of_the_wrong_kind_is_refused_by_name(static_scene, tmp_path):
    """config={"method": "asart"} raised "AttributeError: 'str' object has no attribute 'get'", a
    config.json holding a list the same, config=[...] a TypeError naming no argument, and a
    configuration without a method given with a preset "KeyError: 'method'", and method=""
    ran the default method."""
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"config: at `method`: expected the method's settings"
    ):
        fluidnerf.build_config(static_scene, config={"method": "asart"})
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(fluidnerf.FluidNerfError, match=r"list.json: the configuration must be an object"):
        fluidnerf.build_config(static_scene, config=tmp_path / "list.json")
    with pytest.raises(TypeError, match=r"config: expected a dict or the path of a config.json, got list"):
        fluidnerf.build_config(static_scene, config=[1])
    with pytest.raises(TypeError, match=r"method: expected a method name .* got 3"):
        fluidnerf.build_config(static_scene, 3)
    # An empty name ran the default method ("hybrid"), unannounced.
    with pytest.raises(fluidnerf.FluidNerfError, match=r'method: unknown method "" \(known: asart'):
        fluidnerf.build_config(static_scene, "")
    with pytest.raises(fluidnerf.FluidNerfError, match=r'method: unknown method "" \(known: asart'):
        fluidnerf.reconstruct(static_scene, "", tmp_path / "empty", resolution=8)
    assert not (tmp_path / "empty").exists()
    cfg = fluidnerf.build_config(static_scene, "fast", config={"format": 1, "resolution": 8}, preset="fast")
    assert cfg["method"]["name"] == "fast" and cfg["resolution"] == 8


def test_a_preset_given_with_a_config_keeps_the_configured_start(static_scene, tr_scene):
    """A preset with config= took the preset's field and training and dropped the start: a
    hybrid's voxel method fell back to "auto" and a time-resolved run's start went, as
    --preset with --config did."""
    hybrid = fluidnerf.build_config(static_scene, {"name": "hybrid", "start": {"method": "sart"}})
    cfg = fluidnerf.build_config(static_scene, config=hybrid, preset="dense")
    assert cfg["method"]["preset"] == "dense" and cfg["method"]["start"]["method"] == "sart"
    tr = fluidnerf.build_config(tr_scene, {"name": "tr-fast", "start": {"method": "asart"}, "time_step": 0.5})
    cfg = fluidnerf.build_config(tr_scene, config=tr, preset="tr-small")
    assert cfg["method"]["preset"] == "tr-small"
    assert cfg["method"]["start"]["method"] == "asart" and cfg["method"]["time_step"] == 0.5


def test_a_config_path_to_another_fluidnerf_file_is_named_for_what_it_is(static_scene, tmp_path):
    """config= a scene's synth.json or transforms.json was refused as "configuration: at
    `camera_gains`: unknown field", naming neither the file nor what it is, as --config does."""
    synth = tmp_path / "synth.json"
    synth.write_text(json.dumps({"command": "synth", "settings": {}, "seed": 0}))
    with pytest.raises(
        fluidnerf.FluidNerfError,
        match=r"synth.json: is the settings of a synthetic scene \(synth.json\), not a run's configuration "
        r"\(a run folder's config.json\)",
    ):
        fluidnerf.build_config(static_scene, config=synth)
    with pytest.raises(
        fluidnerf.FluidNerfError, match=r"transforms.json: is a scene file \(transforms.json\)"
    ):
        fluidnerf.build_config(static_scene, config=static_scene.root / "transforms.json")


def test_a_configuration_of_a_folder_without_a_scene_is_refused(static_scene, tmp_path):
    """build_config(path, "asart") of a folder that holds no scene returned a configuration
    whose run could only fail; the folder is now loaded as reconstruct loads it."""
    with pytest.raises(fluidnerf.FluidNerfError, match=r"scene file not found: .*nothing.*transforms.json"):
        fluidnerf.build_config(tmp_path / "nothing", "asart")
    cfg = fluidnerf.build_config(static_scene.root / "transforms.json", "asart")
    assert cfg["scene"] == str(static_scene.root)


def test_a_callback_stops_a_run_and_its_exceptions_propagate(static_scene, tmp_path):
    def stop_at_5(event):
        return not (event["kind"] == "iteration" and event["iteration"] >= 5)

    run = fluidnerf.reconstruct(static_scene, FAST_METHOD, tmp_path / "stopped", callback=stop_at_5, **FAST)
    assert run.status == "interrupted" and run.report["iterations"] == 5

    def boom(event):
        if event["kind"] == "iteration":
            raise RuntimeError("from the callback")

    with pytest.raises(RuntimeError, match="from the callback"):
        fluidnerf.reconstruct(static_scene, FAST_METHOD, tmp_path / "boom", callback=boom, **FAST)
    # The run stopped cleanly and wrote its results.
    assert fluidnerf.open_run(tmp_path / "boom").status == "interrupted"


def test_a_callback_that_returns_numpys_false_stops_the_run(static_scene, tmp_path):
    """A comparison of NumPy numbers is a NumPy boolean: np.False_ was not taken for False, and
    the run went on to its last iteration."""

    def stop_at_5(event):
        return np.float64(event.get("iteration", 0)) < 5

    run = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "stopped", callback=stop_at_5, resolution=8, progress=False
    )
    assert run.status == "interrupted" and run.report["iterations"] == 5


def test_a_runs_volume_is_kept_read_only(static_scene, tmp_path):
    """A change in place of run.volume was kept and seen by every later run.volume, while
    run.field and run.volumes() still read the run's own volume."""
    run = fluidnerf.reconstruct(static_scene, "asart", tmp_path / "run", resolution=8, progress=False)
    kept = run.volume.copy()
    with pytest.raises(ValueError, match="read-only"):
        run.volume[0, 0, 0] = 99.0
    with pytest.raises(ValueError, match="read-only"):
        run.volume -= 1.0
    np.testing.assert_array_equal(run.volume, kept)
    changed = run.volume.copy()
    changed[0, 0, 0] = 99.0
    assert changed[0, 0, 0] == 99.0 and run.volume[0, 0, 0] == kept[0, 0, 0]


def test_a_runs_field_is_evaluated_from_several_threads_at_once(static_scene, tmp_path):
    """field() releases the GIL; a second thread calling it meanwhile was refused with
    "RuntimeError: Already borrowed"."""
    run = fluidnerf.reconstruct(static_scene, "asart", tmp_path / "run", resolution=8, progress=False)
    points = np.random.default_rng(0).uniform(-20, 20, (400_000, 3)).astype(np.float32)
    expected = run.field(points[:10])
    results, errors = [], []

    def evaluate():
        try:
            results.append(run.field(points))
        except Exception as e:  # noqa: BLE001 - every failure is reported below
            errors.append(e)

    threads = [threading.Thread(target=evaluate) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and len(results) == 4
    for r in results:
        np.testing.assert_array_equal(r[:10], expected)


def test_a_callback_that_cannot_be_called_is_refused_before_the_run_starts(static_scene, tmp_path):
    """callback=3 started the run, which stopped at its first event, left an interrupted run
    in the folder and then raised "TypeError: 'int' object is not callable"."""
    with pytest.raises(TypeError, match="callback: expected a function of one event dict, got 3"):
        fluidnerf.reconstruct(static_scene, "asart", tmp_path / "run", callback=3, resolution=8)
    assert not (tmp_path / "run").exists()


def test_a_progress_that_is_no_boolean_is_refused_naming_it_before_the_run_starts(static_scene, tmp_path):
    """progress="no" counted as true, and the run was then refused with "progress=True needs
    tqdm", a value the caller never gave (with tqdm installed, it drew a bar)."""
    for value, shown in [("no", "str 'no'"), (0, "int 0"), ([], r"list \[\]")]:
        with pytest.raises(TypeError, match=rf"progress: expected True, False or None .*, got {shown}$"):
            fluidnerf.reconstruct(static_scene, "asart", tmp_path / "run", progress=value, resolution=8)
    assert not (tmp_path / "run").exists()
    run = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "run", progress=np.bool_(False), resolution=8
    )
    assert run.status == "finished"


def test_ctrl_c_stops_a_run_cleanly(static_scene, tmp_path):
    """SIGINT while the run works (GIL released) stops it at the next iteration: the results are
    written, the report says interrupted, and KeyboardInterrupt reaches the caller."""
    # A process started in the background inherits SIGINT as ignored, and Python then installs
    # no handler: install Python's own for this test.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _interrupt_a_run(static_scene, tmp_path)
    finally:
        signal.signal(signal.SIGINT, previous)


def _interrupt_a_run(static_scene, tmp_path):
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGINT))
    started = time.monotonic()
    timer.start()
    with pytest.raises(KeyboardInterrupt):
        fluidnerf.reconstruct(
            static_scene,
            FAST_METHOD,
            tmp_path / "ctrl-c",
            resolution=16,
            stopping={"rule": "budget", "max_iterations": 1_000_000, "time_budget_s": 60},
            checkpoint_every=0,
        )
    timer.join()
    assert time.monotonic() - started < 30
    run = fluidnerf.open_run(tmp_path / "ctrl-c")
    assert run.status == "interrupted" and 0 < run.report["iterations"] < 1_000_000
    assert run.volume.shape == (16, 16, 16)


def test_a_scene_built_from_arrays_is_reconstructed_in_its_run_folder(static_scene, cli, tmp_path):
    """A scene from arrays is saved into out/scene before its run, and the run was then refused
    because its folder held the scene ("contains the scene folder"), whatever out was."""
    K, poses, _, _ = static_scene.camera_arrays()
    scene = fluidnerf.scene_from_arrays(K, poses, static_scene.images(), static_scene.aabb)
    options = {"resolution": 8, "stopping": {"max_iterations": 2}, "progress": False}
    run = fluidnerf.reconstruct(scene, "asart", tmp_path / "run", **options)
    assert run.status == "finished" and (tmp_path / "run" / "scene" / "transforms.json").is_file()
    assert run.config["scene"] == str((tmp_path / "run" / "scene").absolute())
    first = run.volume  # read before the rerun replaces the files it was opened on
    again = fluidnerf.reconstruct(scene, "asart", tmp_path / "run", overwrite="force", **options)
    np.testing.assert_array_equal(again.volume, first)
    assert (tmp_path / "run" / "scene" / "transforms.json").is_file(), "--force removed the run's scene"
    # The command line reruns it, and replaces it keeping its scene.
    subprocess.run(
        [
            cli,
            "reconstruct",
            "--config",
            str(tmp_path / "run" / "config.json"),
            "-o",
            str(tmp_path / "cli"),
            "-q",
        ],
        check=True,
    )
    np.testing.assert_array_equal(fluidnerf.open_run(tmp_path / "cli").volume, first)
    # A copy reads its own copy of the scene: it named the original's, so it broke when the
    # original was removed.
    copy = run.save(tmp_path / "copy")
    assert copy.config["scene"] == str((tmp_path / "copy" / "scene").resolve())
    shutil.rmtree(tmp_path / "run")
    subprocess.run(
        [
            cli,
            "reconstruct",
            "--config",
            str(tmp_path / "copy" / "config.json"),
            "-o",
            str(tmp_path / "again"),
        ],
        check=True,
        capture_output=True,
    )
    np.testing.assert_array_equal(fluidnerf.open_run(tmp_path / "again").volume, copy.volume)


def test_a_refused_run_of_a_scene_from_arrays_leaves_its_folder_as_it_was(static_scene, tmp_path):
    """The scene was saved into out/scene before the folder was checked: a refused run left a
    scene inside another run's folder, and into a file failed with "Not a directory"."""
    K, poses, _, _ = static_scene.camera_arrays()
    scene = fluidnerf.scene_from_arrays(K, poses, static_scene.images(), static_scene.aabb)
    options = {"resolution": 8, "stopping": {"max_iterations": 2}, "progress": False}
    fluidnerf.reconstruct(static_scene, "asart", tmp_path / "finished", **options)
    before = sorted(p.name for p in (tmp_path / "finished").iterdir())
    with pytest.raises(fluidnerf.FluidNerfError, match="finished: already holds a finished run"):
        fluidnerf.reconstruct(scene, "asart", tmp_path / "finished", **options)
    assert sorted(p.name for p in (tmp_path / "finished").iterdir()) == before
    (tmp_path / "file").write_text("x")
    with pytest.raises(fluidnerf.FluidNerfError, match="file: exists and is not a folder"):
        fluidnerf.reconstruct(scene, "asart", tmp_path / "file", **options)
    with pytest.raises(fluidnerf.FluidNerfError, match="nothing to resume"):
        fluidnerf.reconstruct(scene, "fast", tmp_path / "new", overwrite="resume", **options)
    assert not (tmp_path / "new").exists()
    # Nor is one refused for its settings: the scene was saved before they were checked.
    with pytest.raises(
        fluidnerf.FluidNerfError, match="stopping.max_iterations: must be 1 to 1000000000 iterations, got 0"
    ):
        fluidnerf.reconstruct(
            scene, "asart", tmp_path / "new", **{**options, "stopping": {"max_iterations": 0}}
        )
    assert not (tmp_path / "new").exists()
    # Nor one refused by the run, after the scene was saved: it left out/scene, and the same
    # call, corrected, was then refused for the scene it had left ("pass force=True").
    # Its message names the setting a Python caller raises, not only the command line's flag.
    with pytest.raises(
        fluidnerf.FluidNerfError,
        match=r"needs about .* are allowed \(--memory-limit, memory_limit_gib\).*memory_limit_gib in a "
        "configuration and from Python",
    ):
        fluidnerf.reconstruct(scene, "asart", tmp_path / "new", memory_limit_gib=1e-6, **options)
    assert not (tmp_path / "new").exists() and scene.root is None
    run = fluidnerf.reconstruct(scene, "asart", tmp_path / "new", **options)
    assert run.status == "finished" and scene.root == (tmp_path / "new" / "scene").absolute()


def test_a_refused_run_into_a_temporary_folder_leaves_none_behind(static_scene, tmp_path, monkeypatch):
    """Without `out` every call made a temporary run folder first, and each call refused for its
    settings (or for a scene built from arrays, its folder) left an empty one behind."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    from_arrays = fluidnerf.scene_from_arrays(
        *static_scene.camera_arrays()[:2], static_scene.images(), static_scene.aabb
    )
    for scene, method, options in [
        (static_scene, "asart", {"resolution": -1}),
        (static_scene, "asart", {"resolutoin": 8}),
        (static_scene, "nope", {}),
        (static_scene, "asart", {"overwrite": "bogus"}),
        (from_arrays, "asart", {"resolution": -1}),
        (from_arrays, "asart", {"overwrite": "bogus"}),
    ]:
        with pytest.raises(fluidnerf.FluidNerfError):
            fluidnerf.reconstruct(scene, method, progress=False, **options)
        assert list(tmp_path.iterdir()) == [], (method, options)
    run = fluidnerf.reconstruct(static_scene, "asart", resolution=8, progress=False)
    assert run.path.parent == tmp_path and run.status == "finished"


def test_a_resume_with_another_method_is_refused_and_leaves_the_run(static_scene, tmp_path):
    """A resume given another run's configuration (a voxel method's, or another neural method's)
    wrote that method's results over the run in the folder, leaving a folder of two runs' files
    that open_run then refused; the command line refuses both from its options."""
    short = dict(FAST, stopping={"rule": "budget", "max_iterations": 3})
    fluidnerf.reconstruct(static_scene, FAST_METHOD, tmp_path / "r", progress=False, **short)
    voxel = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "v", resolution=8, stopping={"max_iterations": 2}, progress=False
    )
    before = {p.name: p.read_bytes() for p in (tmp_path / "r").iterdir()}
    with pytest.raises(fluidnerf.FluidNerfError, match="asart is a voxel method, which keeps no checkpoint"):
        fluidnerf.reconstruct(
            static_scene,
            out=tmp_path / "r",
            config=voxel.path / "config.json",
            overwrite="resume",
            progress=False,
        )
    other = fluidnerf.build_config(static_scene, "hybrid", **short)
    with pytest.raises(
        fluidnerf.FluidNerfError, match="holds a run of method fast, which a resume continues"
    ):
        fluidnerf.reconstruct(
            static_scene, out=tmp_path / "r", config=other, overwrite="resume", progress=False
        )
    assert {p.name: p.read_bytes() for p in (tmp_path / "r").iterdir()} == before
    assert fluidnerf.open_run(tmp_path / "r").report["iterations"] == 3


def test_a_start_run_inside_the_folder_a_forced_run_replaces_is_refused(static_scene, tmp_path):
    """Starting from the run in ``out`` itself with ``overwrite="force"`` removed that run before
    its start was read, then refused the start as holding nothing: the run was lost."""
    voxel = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "a", resolution=8, stopping={"max_iterations": 2}, progress=False
    )
    before = voxel.volume.copy()
    method = dict(FAST_METHOD, start={"run": str(tmp_path / "a")})
    with pytest.raises(
        fluidnerf.FluidNerfError, match="is the run in the output folder .* or one of its start runs"
    ):
        fluidnerf.reconstruct(static_scene, method, tmp_path / "a", overwrite="force", progress=False, **FAST)
    np.testing.assert_array_equal(fluidnerf.open_run(tmp_path / "a").volume, before)


def test_a_refused_force_or_resume_of_a_scene_from_arrays_leaves_the_run_as_it_was(static_scene, tmp_path):
    """A refused ``overwrite="force"`` (too little memory: refused by the run's own checks)
    emptied the run's folder but for the new scene, and a refused ``overwrite="resume"`` (other
    images) left the new images over the run's own scene, so the run could never be resumed."""
    K, poses, _, _ = static_scene.camera_arrays()
    images = static_scene.images()
    out = tmp_path / "run"
    options = {"resolution": 8, "progress": False}
    fluidnerf.reconstruct(
        fluidnerf.scene_from_arrays(K, poses, images, static_scene.aabb),
        FAST_METHOD,
        out,
        stopping={"max_iterations": 6},
        checkpoint_every=3,
        callback=lambda e: not (e["kind"] == "iteration" and e["iteration"] == 4),
        **options,
    )
    files = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    volume = fluidnerf.open_run(out).volume
    other = fluidnerf.scene_from_arrays(K, poses, images + 1.0, static_scene.aabb)
    with pytest.raises(fluidnerf.FluidNerfError, match="memory"):
        fluidnerf.reconstruct(other, "asart", out, overwrite="force", memory_limit_gib=1e-6, **options)
    with pytest.raises(fluidnerf.FluidNerfError, match="other images or cameras"):
        fluidnerf.reconstruct(other, FAST_METHOD, out, overwrite="resume", **options)
    assert other.root is None, "the scene is back in memory, as given"
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == files
    np.testing.assert_array_equal(fluidnerf.load_scene(out / "scene").images(), images)
    np.testing.assert_array_equal(fluidnerf.open_run(out).volume, volume)
    # The run resumes on its own scene, and a forced run on another replaces it and its scene.
    resumed = fluidnerf.reconstruct(
        fluidnerf.scene_from_arrays(K, poses, images, static_scene.aabb),
        FAST_METHOD,
        out,
        overwrite="resume",
        **options,
    )
    assert resumed.report["iterations"] == 6
    forced = fluidnerf.reconstruct(
        other, "asart", out, overwrite="force", stopping={"max_iterations": 2}, **options
    )
    assert forced.status == "finished" and not (out / ".scene-replaced").exists()
    np.testing.assert_array_equal(fluidnerf.load_scene(out / "scene").images(), images + 1.0)


def _killed_saving_scene(out, arrays, kill_on):
    """A call, in a process of its own, that replaces the run in ``out`` by one on the scene of
    ``arrays`` (an ``.npz`` of ``K``, ``poses``, ``images``, ``aabb``) and is killed outright
    (SIGKILL): right after the scene is saved (``kill_on`` None), or at the run's first event
    of kind ``kill_on``."""
    code = f"""
import os, pathlib, signal
import numpy as np
import fluidnerf
from fluidnerf._api import _SavedScene
a = np.load({str(arrays)!r})
scene = fluidnerf.scene_from_arrays(a["K"], a["poses"], a["images"], a["aabb"])
def kill(event=None):
    if event is None or event["kind"] == {kill_on!r}:
        os.kill(os.getpid(), signal.SIGKILL)
if {kill_on!r} is None:
    _SavedScene(scene, pathlib.Path({str(out)!r}), replace=True).save(force=True)
    kill()
fluidnerf.reconstruct(
    scene, "asart", {str(out)!r}, overwrite="force", resolution=8, progress=False,
    stopping={{"max_iterations": 50}}, callback=kill,
)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == -signal.SIGKILL, done.stderr


def test_a_scene_from_arrays_left_aside_by_a_killed_call_is_settled_by_the_next(static_scene, tmp_path):
    """A call killed outright between saving its scene over the run's own and its run writing
    ``config.json`` left the run's scene in ``.scene-replaced``, and the next call removed it:
    the folder's run was then read with the killed call's images. The run is now read with its
    own scene again; once the killed call's run had written, its scene is the run's."""
    K, poses, _, _ = static_scene.camera_arrays()
    images = static_scene.images()
    out = tmp_path / "run"
    options = {"resolution": 8, "progress": False, "stopping": {"max_iterations": 2}}
    scene = fluidnerf.scene_from_arrays(K, poses, images, static_scene.aabb)
    volume = fluidnerf.reconstruct(scene, "asart", out, **options).volume
    arrays = tmp_path / "other.npz"
    np.savez(arrays, K=K, poses=poses, images=images + 1.0, aabb=np.asarray(static_scene.aabb))
    _killed_saving_scene(out, arrays, None)
    assert (out / ".scene-replaced").is_dir()
    np.testing.assert_array_equal(fluidnerf.load_scene(out / "scene").images(), images + 1.0)
    # A reader settles it: the run comes with the scene it was made on.
    np.testing.assert_array_equal(fluidnerf.open_run(out).volume, volume)
    np.testing.assert_array_equal(fluidnerf.load_scene(out / "scene").images(), images)
    assert not (out / ".scene-replaced").exists() and not (out / ".scene-replaced.json").exists()
    # Killed once its run had started on the new scene: the old scene goes, and the run
    # replaced next is the new scene's.
    _killed_saving_scene(out, arrays, "iteration")
    assert (out / ".scene-replaced").is_dir() and not (out / "report.json").exists()
    again = fluidnerf.scene_from_arrays(K, poses, images + 1.0, static_scene.aabb)
    forced = fluidnerf.reconstruct(again, "asart", out, overwrite="force", **options)
    assert forced.status == "finished" and not (out / ".scene-replaced").exists()
    np.testing.assert_array_equal(fluidnerf.load_scene(out / "scene").images(), images + 1.0)


@pytest.mark.parametrize("method", ["asart", "fast"])
def test_a_run_is_scored_on_the_held_out_camera_as_eval_scores_it(static_scene, cli, method, tmp_path):
    """``Run.score_held_out`` gives the rows ``fluidnerf eval`` writes into metrics.json for the
    same run (a voxel run and a field), through the same library function: the measure a
    Python user compares methods by on a recording without ground truth."""
    if method == "fast":
        run = fluidnerf.reconstruct(static_scene, FAST_METHOD, tmp_path / "r", progress=False, **FAST)
    else:
        stop = {"max_iterations": 3}
        run = fluidnerf.reconstruct(
            static_scene, method, tmp_path / "r", resolution=12, stopping=stop, progress=False
        )
    rows = run.score_held_out()
    assert [r["frame"] for r in rows] == [3]
    assert 0.0 < rows[0]["nrmse"] < 1.5 and rows[0]["pixels"] == 400
    assert rows == run.score_held_out(static_scene.root, supersample=2)
    out = subprocess.run(
        [cli, "eval", str(run.path), "--no-regions", "--json", str(tmp_path / "m.json"), "-q"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    expected = json.loads((tmp_path / "m.json").read_text())["reprojection"]
    assert rows == expected
    # Fewer rays per pixel render another image; the supersampling is the caller's to choose.
    assert run.score_held_out(supersample=1)[0]["nrmse"] != rows[0]["nrmse"]
    # Through the volume the run wrote, as eval --use-volume and study score it.
    out = subprocess.run(
        [
            cli,
            "eval",
            str(run.path),
            "--use-volume",
            "--no-regions",
            "--json",
            str(tmp_path / "v.json"),
            "-q",
        ],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    from_volume = run.score_held_out(use_volume=True)
    assert from_volume == json.loads((tmp_path / "v.json").read_text())["reprojection"]
    assert (from_volume == rows) == (method == "asart")


def test_scoring_on_held_out_cameras_refuses_what_it_cannot_score(static_scene, tmp_path):
    """A scene that holds no camera out has nothing to score on, and a supersampling out of
    range is refused, each naming the argument."""
    run = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "r", resolution=8, stopping={"max_iterations": 2}, progress=False
    )
    K, poses, _, _ = static_scene.camera_arrays()
    whole = fluidnerf.scene_from_arrays(K, poses, static_scene.images(), static_scene.aabb)
    whole.save(tmp_path / "whole")
    with pytest.raises(fluidnerf.FluidNerfError, match="holds no frame out"):
        run.score_held_out(whole)
    with pytest.raises(fluidnerf.FluidNerfError, match="supersample: must be between 1 and 64"):
        run.score_held_out(supersample=65)
    with pytest.raises(TypeError, match="use_volume: expected True or False"):
        run.score_held_out(use_volume="yes")


@pytest.fixture(scope="module")
def stopped_tr_run(tr_holdout_scene, tmp_path_factory) -> fluidnerf.Run:
    """A time-resolved run of ``tr_holdout_scene`` stopped in its first window: it trained
    t = 14 and 14.5, not 15 and 15.5."""

    def stop(event: dict) -> bool | None:
        first_window = event["kind"] == "iteration" and event["window"] == 0
        return False if first_window and event["iteration"] == 3 else None

    out = tmp_path_factory.mktemp("stopped") / "run"
    with pytest.warns(fluidnerf.FluidNerfWarning, match="stopped before it reached t = 15, 15.5"):
        run = fluidnerf.reconstruct(
            tr_holdout_scene, TR_METHOD, out, callback=stop, progress=False, **TR_OPTIONS
        )
    assert run.report["not_reached"] == [15.0, 15.5]
    return run


def _eval(cli: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([cli, "eval", *args, "--no-regions"], capture_output=True, text=True)


def test_a_stopped_time_resolved_run_is_not_scored_at_instants_it_never_trained(
    stopped_tr_run, cli, tmp_path
):
    """A time-resolved run stopped before its last instants was scored on the held-out frames
    there too, through its field held at the last instant it trained or, with
    ``use_volume=True``, the volume nearest in time, where ``fluidnerf eval`` refuses it. Both
    refuse it now, with one message naming the instant and how to continue the run."""
    refusal = (
        "time 15 was never trained: the run was stopped before it reached t = 15, 15.5 (its windows trained "
        '14 … 14.5); continue it with `reconstruct --resume` (`overwrite="resume"` from Python)'
    )
    for use_volume in ([], ["--use-volume"]):
        out = _eval(cli, str(stopped_tr_run.path), "--json", str(tmp_path / "m.json"), *use_volume)
        assert out.returncode != 0 and refusal in out.stderr, out.stderr
    frame = f"{stopped_tr_run.path}: the scene's held-out frame images/cam004_t02.png: {refusal}"
    for use_volume in (False, True):
        with pytest.raises(fluidnerf.FluidNerfError, match=re.escape(frame)):
            stopped_tr_run.score_held_out(use_volume=use_volume)


def test_a_time_resolved_run_is_refused_a_scene_without_times_as_eval_refuses_it(
    stopped_tr_run, static_scene, cli, tmp_path
):
    """A time-resolved run scored against a static scene (frames without a time) gave numbers,
    its field at its first instant, where ``fluidnerf eval`` refuses it; the scene not being the
    run's own went unsaid, where eval warns of it."""
    out = _eval(
        cli, str(stopped_tr_run.path), "--scene", str(static_scene.root), "--json", str(tmp_path / "m.json")
    )
    refusal = "has no time, but the run is time-resolved (instants 14 … 14.5)"
    assert out.returncode != 0 and refusal in out.stderr, out.stderr
    for use_volume in (False, True):
        with pytest.warns(fluidnerf.FluidNerfWarning) as caught:
            with pytest.raises(fluidnerf.FluidNerfError) as refused:
                stopped_tr_run.score_held_out(static_scene, use_volume=use_volume)
        frame = f"{stopped_tr_run.path}: the scene's held-out frame images/cam003.png {refusal}"
        assert frame in str(refused.value)
        other = f"was made from the scene {stopped_tr_run.config['scene']}, not {static_scene.root}"
        assert [w.filename for w in caught] == [__file__]
        assert other in str(caught[0].message) and str(caught[0].message) in out.stderr


def test_a_run_scored_against_another_scene_or_box_is_warned_of_as_eval_warns(static_scene, cli, tmp_path):
    """A run scored against another scene than its own, whose box is not the run's, was scored
    without a word, where ``fluidnerf eval`` warns of both. The same warnings are issued, at the
    caller's line, and the rows are eval's."""
    run = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "run", resolution=8, stopping={"max_iterations": 2}, progress=False
    )
    other = tmp_path / "other"
    shutil.copytree(static_scene.root, other)
    transforms = json.loads((other / "transforms.json").read_text())
    transforms["aabb"] = [[-25.0, -20.0, -20.0], [25.0, 20.0, 20.0]]
    (other / "transforms.json").write_text(json.dumps(transforms))
    with pytest.warns(fluidnerf.FluidNerfWarning) as caught:
        rows = run.score_held_out(other)
    out = _eval(cli, str(run.path), "--scene", str(other), "--json", str(tmp_path / "m.json"))
    assert out.returncode == 0, out.stderr
    assert rows == json.loads((tmp_path / "m.json").read_text())["reprojection"]
    messages = [str(w.message) for w in caught]
    assert len(messages) == 2 and [w.filename for w in caught] == [__file__] * 2
    assert (
        f"{run.path} was made from the scene {static_scene.root}, not {other}; scored against this one"
        in messages
    )
    box = f"the run in {run.path} fills the box [-20, -20, -20] .. [20, 20, 20], not the scene's [-25, -20, -20]"
    assert any(m.startswith(box) for m in messages), messages
    assert all(m in out.stderr for m in messages), out.stderr


def test_a_time_resolved_runs_volumes_are_scored_at_their_own_instants_only(tr_holdout_scene, cli, tmp_path):
    """With ``use_volume=True`` a held-out frame was scored against the volume nearest its
    time, another instant's where the run wrote none at its own. Each frame is scored against
    the volume of its instant, as ``fluidnerf eval --use-volume`` scores it, and a frame at an
    instant without a volume is refused, naming it; the field is sampled at any trained time."""
    run = fluidnerf.reconstruct(tr_holdout_scene, TR_METHOD, tmp_path / "run", progress=False, **TR_OPTIONS)
    rows = run.score_held_out(use_volume=True)
    out = _eval(cli, str(run.path), "--use-volume", "--json", str(tmp_path / "m.json"))
    assert out.returncode == 0, out.stderr
    assert rows == json.loads((tmp_path / "m.json").read_text())["reprojection"]
    assert [r["time"] for r in rows] == [14.0, 14.5, 15.0, 15.5]
    # The held-out frame of t = 14.5 moved to t = 14.25, where the run wrote no volume.
    other = tmp_path / "other"
    shutil.copytree(tr_holdout_scene.root, other)
    transforms = json.loads((other / "transforms.json").read_text())
    (moved,) = [f for f in transforms["frames"] if f.get("holdout") and f["time"] == 14.5]
    moved["time"] = 14.25
    (other / "transforms.json").write_text(json.dumps(transforms))
    with pytest.warns(fluidnerf.FluidNerfWarning, match="was made from the scene"):
        with pytest.raises(
            fluidnerf.FluidNerfError,
            match=re.escape(
                f"{run.path}: the run wrote no volume at t = 14.25, the time of the scene's held-out frame "
                "images/cam004_t01.png (it wrote them at t = 14, 14.5, 15, 15.5); score its trained field instead"
            ),
        ):
            run.score_held_out(other, use_volume=True)
    with pytest.warns(fluidnerf.FluidNerfWarning, match="was made from the scene"):
        assert [r["time"] for r in run.score_held_out(other)] == [14.0, 14.25, 15.0, 15.5]


def test_a_run_opened_from_a_relative_folder_stays_that_run_after_a_change_of_folder(
    static_scene, tmp_path, monkeypatch
):
    """A Run kept its folder as given and read its files again from the working directory of
    the moment: after os.chdir it read another folder's run of the same name, or failed."""
    monkeypatch.chdir(tmp_path)
    run = fluidnerf.reconstruct(
        static_scene, "asart", "run", resolution=6, stopping={"max_iterations": 2}, progress=False
    )
    opened = fluidnerf.open_run("run")
    assert run.path.is_absolute() and opened.path == tmp_path / "run"
    expected = run.volume.copy()
    elsewhere = tmp_path / "elsewhere"
    shutil.copytree(tmp_path / "run", elsewhere / "run", copy_function=shutil.copy2)
    np.save(elsewhere / "run" / "volume.npy", np.ones_like(expected))
    os.utime(elsewhere / "run" / "volume.npy", ns=(0, os.stat(tmp_path / "run" / "volume.npy").st_mtime_ns))
    monkeypatch.chdir(elsewhere)
    np.testing.assert_array_equal(opened.volume, expected)
    np.testing.assert_array_equal(opened.volumes()[0][1], expected)
    # A folder that is gone is said to be gone.
    shutil.rmtree(tmp_path / "run")
    with pytest.raises(fluidnerf.FluidNerfError, match="the run folder .* no longer exists"):
        opened.volumes()


def test_a_time_given_to_a_static_result_is_warned_of_at_the_callers_line(static_scene, tmp_path):
    run = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "a", resolution=6, stopping={"max_iterations": 1}, progress=False
    )
    with pytest.warns(fluidnerf.FluidNerfWarning, match="no effect") as caught:
        run.field(np.zeros((1, 3)), time=1.0)
    assert [w.filename for w in caught] == [__file__]


def test_a_time_held_out_at_an_end_is_warned_of_as_the_command_line_does(tr_scene, tmp_path):
    method = {"name": "tr-fast", "holdout_times": [16.0]}
    with pytest.warns(fluidnerf.FluidNerfWarning, match="held-out time 16 lies outside the training times"):
        run = fluidnerf.reconstruct(
            tr_scene, method, tmp_path / "a", resolution=6, stopping={"max_iterations": 2}, progress=False
        )
    with pytest.warns(fluidnerf.FluidNerfWarning, match="t = 16 held out at an end") as caught:
        held = run.field(np.zeros((1, 3)), time=16.0)
    assert [w.filename for w in caught] == [__file__]
    # The field repeats the last trained instant there, as the run scored it.
    assert held.tolist() == run.field(np.zeros((1, 3)), time=15.5).tolist()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        run.field(np.zeros((1, 3)), time=15.0)


def test_resuming_a_folder_with_another_method_says_what_resuming_runs(static_scene, tmp_path):
    fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "a", resolution=6, stopping={"max_iterations": 1}, progress=False
    )
    with pytest.raises(
        fluidnerf.FluidNerfError, match='holds a run of method asart, which overwrite="resume"'
    ):
        fluidnerf.reconstruct(static_scene, "mlem", tmp_path / "a", overwrite="resume", progress=False)


def test_a_configuration_built_for_a_scene_in_memory_names_no_other_scene(static_scene, tmp_path):
    run = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "a", resolution=6, stopping={"max_iterations": 1}, progress=False
    )
    K, poses, _, _ = static_scene.camera_arrays()
    memory = fluidnerf.scene_from_arrays(K, poses, static_scene.images(), static_scene.aabb)
    assert fluidnerf.build_config(memory, config=run.path / "config.json")["scene"] == ""
    assert fluidnerf.build_config(static_scene, config=run.path / "config.json")["scene"] == str(
        Path(static_scene.root).absolute()
    )


def test_flags_are_true_or_false_numpy_booleans_too(static_scene, tmp_path):
    run = fluidnerf.reconstruct(
        static_scene, "asart", tmp_path / "a", resolution=6, stopping={"max_iterations": 1}, progress=False
    )
    assert run.score_held_out(use_volume=np.True_) == run.score_held_out(use_volume=True)
    with pytest.raises(TypeError, match="force: expected True or False, got int 1"):
        fluidnerf.synth(tmp_path / "s", "demo", force=1)
    with pytest.raises(TypeError, match="force: expected True or False, got str 'no'"):
        static_scene.save(tmp_path / "t", force="no")
    with pytest.raises(TypeError, match="preset: expected a string"):
        fluidnerf.synth(tmp_path / "s", None)
    with pytest.raises(
        fluidnerf.FluidNerfError, match="unknown preset `demoo`; the presets are demo, planar15"
    ):
        fluidnerf.synth(tmp_path / "s", "demoo")
