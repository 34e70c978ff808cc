"""Scale-out on Dask: a long time-resolved recording reconstructed window by window.

A time-resolved run (``tr-fast``, ``tr-fluidnerf``, ``static-per-frame``) trains its frames
in windows (``fluidnerf.window_plan``). :func:`reconstruct` makes every window a Dask task
that runs ``fluidnerf_pipeline::reconstruct_windows`` for that window into the run folder, and
a last task that stitches them (``finish_windows``) into exactly the run folder the serial
``fluidnerf.reconstruct`` writes, with the same volumes for the same settings and seed.

- Warm-start chains are respected: with ``warm_start`` (the default of ``tr-fluidnerf``)
  window ``k`` depends on window ``k − 1``; without it (the default of ``tr-fast``, and
  ``static-per-frame``, one window per frame) every window is independent and they run in
  parallel.
- Tasks are idempotent and their outputs atomic: a window whose done file
  (``windows/wNNN.done.json``) exists is read back, not trained again; a window whose process
  died continues from its checkpoint. A lost worker's task is simply run again elsewhere.
- The run folder must be on a file system every worker sees (and the scene too).

Training is deterministic per seed and per thread count of the Rust thread pool, so the
windows equal the serial run's when the workers have as many cores as the machine that runs
the serial run (set ``RAYON_NUM_THREADS`` to pin it).
"""

from __future__ import annotations

import json
import os
import time
import uuid
from pathlib import Path
from typing import Any, Callable

import numpy as np

from . import _fluidnerf as _ext
from ._api import (
    FluidNerfError,
    PathLike,
    Run,
    Scene,
    _as_scene,
    _check_callback,
    _integer,
    _path,
    _SavedScene,
    _string,
    _warn,
    build_config,
    open_run,
)

__all__ = ["finish", "reconstruct", "train_window"]


def train_window(scene_root: str, config_json: str, out: str, window: int, *_after: Any) -> dict:
    """The task of one window: trains window ``window`` into ``out`` (or reads it back when it
    finished before) and returns its outcome, with the run's warnings it gave (``"warnings"``:
    a worker's own warnings reach nobody). ``_after`` are the results of the tasks it must wait
    for (the window it warm-starts from); only their completion matters."""
    scene_root, config_json, out = _task_arguments(scene_root, config_json, out)
    scene = Scene.load(scene_root)
    k = _integer(window, "window")
    plan = json.loads(_ext.window_plan(scene, config_json))["windows"]
    if not 0 <= k < len(plan):
        # Not left to the extension, whose unsigned window index made a negative one a bare
        # OverflowError naming no argument.
        raise FluidNerfError(
            f"window: {k} is not in the plan: the run has {len(plan)} window(s), 0 to {len(plan) - 1} "
            f"(frames {plan})"
        )
    lock = f"w{k:03d}.lock"
    given: list[str] = []

    def on_event(event: dict) -> None:
        if event["kind"] == "warning" and event["message"] not in given:
            given.append(event["message"])

    started = time.monotonic()
    waits = 0
    while True:
        try:
            outcomes = json.loads(_ext.reconstruct_windows(scene, config_json, out, k, k + 1, on_event))
            return {**outcomes[0], "warnings": given}
        except FluidNerfError as e:
            # Another task of this window still trains it (Dask ran the task again, on a
            # worker it thought lost, or a second call was made meanwhile): its outcome is
            # read back once it finishes, and its checkpoint continued should it die. Failing
            # here failed the whole run, as if the window were another run's. A holder on
            # another machine that died stops refreshing the lock, which is then replaced
            # (fluidnerf_pipeline's LOCK_STALE_AFTER, two minutes): the wait ends by itself.
            # Only a lock that is never replaced (an earlier fluidnerf's, which its refusal
            # says to remove by hand) is not waited for.
            message = str(e)
            holding = "is in use by another run" in message and lock in message
            if not holding or "remove the lock file" in message:
                if waits:
                    raise FluidNerfError(
                        f"window {k}: {message} (after waiting {time.monotonic() - started:.0f} s for another "
                        f"task that held its lock {lock}, {waits} attempt(s))"
                    ) from e
                raise
        waits += 1
        # Soon at first (a duplicate task usually ends in moments), then every second: a holder
        # may train the window for hours.
        time.sleep(min(0.1 * waits, 1.0))


def finish(scene_root: str, config_json: str, out: str, *_after: Any) -> dict:
    """The last task: stitches the finished windows and writes the run's results; returns the
    report. Run again after it finished, it writes the same results again."""
    scene_root, config_json, out = _task_arguments(scene_root, config_json, out)
    scene = Scene.load(scene_root)
    return json.loads(_ext.finish_windows(scene, config_json, out, None))


def _task_arguments(scene_root: Any, config_json: Any, out: Any) -> tuple[str, str, str]:
    """A task's arguments checked, each refused naming it (``Scene.load`` named its own
    argument, ``folder``, and the extension a string's as pyo3 does)."""
    return _path(scene_root, "scene_root"), _string(config_json, "config_json"), _path(out, "out")


def _whole_run(scene_root: str, config_json: str, out: str, overwrite: str = "refuse") -> dict:
    scene = Scene.load(scene_root)
    return json.loads(_ext.reconstruct(scene, config_json, out, overwrite, None))


def _same_scene(scene: Scene, saved: Path) -> Scene:
    """The scene saved in ``saved`` when ``scene`` (built from arrays, not saved) holds the
    same cameras, images and settings; else refused, leaving both as they are."""
    kept = Scene.load(os.fspath(saved))
    same = (
        len(scene) == len(kept)
        and all(np.array_equal(a, b) for a, b in zip(scene.camera_arrays(), kept.camera_arrays()))
        and np.array_equal(scene.aabb, kept.aabb)
        and (scene.times, scene.holdout, scene.names) == (kept.times, kept.holdout, kept.names)
        and (scene.units, scene.intensity_scale) == (kept.units, kept.intensity_scale)
        and all(np.array_equal(a, b) for a, b in zip(scene.images(), kept.images()))
    )
    if not same:
        raise FluidNerfError(
            f"{saved}: holds the scene an earlier call saved, and the scene given differs from it "
            "(its cameras, images or settings); the run's windows are trained on the saved one: give "
            "that scene (fluidnerf.Scene.load of the folder) or the same arrays, or another output folder"
        )
    return kept


def reconstruct(
    client: Any,
    scene: Scene | PathLike,
    method: str | dict | None = None,
    out: PathLike | None = None,
    *,
    config: dict | PathLike | None = None,
    preset: str | None = None,
    overwrite: str = "refuse",
    callback: Callable[[dict], None] | None = None,
    **options: Any,
) -> Run:
    """Reconstructs ``scene`` on the Dask cluster of ``client`` (a ``distributed.Client``)
    into the run folder ``out``, window by window, and returns the finished :class:`Run`.

    Settings as :func:`fluidnerf.reconstruct` (``options`` are ``RunConfig`` keys; ``method``
    None runs the method of ``config``, or without one ``"tr-fast"`` for a scene whose frames
    hold several times and ``"hybrid"`` otherwise). A static method (not time-resolved) runs
    as a single task, into a folder ``overwrite`` allows as for :func:`fluidnerf.reconstruct`
    (``"refuse"``, ``"force"`` or ``"resume"``). A time-resolved run continues the windows
    its folder holds whenever it is called again; it takes ``"refuse"`` or ``"resume"``
    (the same, but for a folder that holds the run's report: a finished run, or one in one
    piece that was interrupted, is refused, or with ``"resume"`` resumed as
    :func:`fluidnerf.reconstruct` resumes it, in a single task that reads its finished windows
    back, trains any missing and writes the results again), and is never replaced
    (``"force"`` is refused: remove the folder). ``callback(event)`` receives
    ``{"kind": "window_finished", "window": k, "windows": n, "reused": bool, ...}`` as windows
    complete. The run's warnings are issued here as :class:`fluidnerf.FluidNerfWarning`, each
    once, as :func:`fluidnerf.reconstruct` issues them. Calling it again on the same folder reuses every finished window, so an
    interrupted scale-out continues where it stopped; a scene built from arrays may be built
    again for that call, and must then be the same scene as the one the first call saved in
    ``out/scene``.
    """
    _check_callback(callback)
    if overwrite not in ("refuse", "force", "resume"):
        raise FluidNerfError(f"overwrite: expected 'refuse', 'force' or 'resume', got {overwrite!r}")
    scene = _as_scene(scene)
    if out is None:
        raise ValueError("out: a run folder on a file system every worker sees is needed")
    out_path = Path(_path(out, "out")).absolute()
    if overwrite == "resume" and config is None and (out_path / "config.json").is_file():
        # A resumed run continues with the settings it was started with (as --resume).
        config = out_path / "config.json"
    cfg = build_config(scene, method, config=config, preset=preset, **options)
    whole = cfg["method"]["name"] not in ("tr-fluidnerf", "tr-fast", "static-per-frame")
    if not whole and overwrite == "resume" and (out_path / "report.json").is_file():
        # A time-resolved run that holds its report (finished, or a run in one piece that was
        # interrupted) is resumed as fluidnerf.reconstruct and `reconstruct --resume` resume
        # it: in one task, which reads back every finished window, trains any missing and
        # writes the results again. Its windows are not trained one at a time into it
        # (check_window_folder refuses the folder: a report would sit beside windows of a run
        # not finished), which refused the resumed run outright.
        whole = True
    if not whole and overwrite == "force":
        raise FluidNerfError(
            f"overwrite: a time-resolved run on Dask continues the windows {out_path} holds whenever it is "
            "called again, and is never replaced: to train it afresh, remove the folder or choose another"
        )
    # The folder is checked here, before any task: the workers would refuse it only after
    # they were sent the run. For a scene built from arrays, also before the scene is written
    # into it: a refused run leaves the folder as it was. A whole run's refusal names
    # overwrite="force" and "resume", which it takes.
    if whole:
        _ext.check_run_folder(os.fspath(out_path), overwrite)
    else:
        _ext.check_window_folder(os.fspath(out_path))
    if not callable(getattr(client, "submit", None)):
        # Found at the first task, as "AttributeError: 'NoneType' object has no attribute
        # 'submit'", after a scene built from arrays was saved into the folder, and left there.
        raise TypeError(
            f"client: expected a Dask client (distributed.Client) to run the tasks on, got {type(client).__name__} "
            f"{client!r}"
        )
    saved: _SavedScene | None = None
    if scene.root is None:
        own = out_path / "scene"
        if own.exists() and not (whole and overwrite != "refuse"):
            # A call that continues an interrupted one, with the scene built again from its
            # arrays: the windows already trained were trained on the scene saved then, so it
            # must be the same scene, and the saved one is never overwritten.
            scene = _same_scene(scene, own)
        else:
            # A whole run replaced or resumed continues on the scene given, saved over the run's
            # own, as fluidnerf.reconstruct does.
            saved = _SavedScene(scene, out_path, replace=whole and overwrite != "refuse")
            saved.save(force=own.exists())
        cfg["scene"] = str(Path(os.fspath(scene.root)).absolute())
    try:
        run = _run(client, scene, cfg, out_path, whole, overwrite, callback)
    except FluidNerfError:
        # A run refused before it wrote anything takes back the scene this call saved, and puts
        # back the one it replaced.
        if saved is not None:
            saved.take_back()
        raise
    except BaseException:
        # Stopped otherwise (its tasks may still run on the workers): the saved scene stays, so
        # that the same call can continue; the one it replaced goes only once the run has
        # written on the saved one, or comes back if it never does (settled by the next call or
        # reader of the folder).
        if saved is not None:
            if saved.written():
                saved.finish()
            else:
                saved.release()
        raise
    if saved is not None:
        saved.finish()
    return run


def _run(
    client: Any,
    scene: Scene,
    cfg: dict,
    out_path: Path,
    whole: bool,
    overwrite: str,
    callback: Callable[[dict], None] | None,
) -> Run:
    """The tasks of :func:`reconstruct`, submitted to ``client``, and the finished run."""
    from distributed import as_completed

    cfg_json = json.dumps(cfg)
    root = str(scene.root)
    token = uuid.uuid4().hex[:8]
    # The run's warnings, issued on the worker, reached nobody: they are issued here, each once,
    # as fluidnerf.reconstruct issues them, as the windows' tasks and then the run report them.
    issued: set[str] = set()

    def warn(messages: list[str]) -> None:
        for message in messages:
            if message not in issued:
                issued.add(message)
                _warn(message)

    if whole:
        report = client.submit(
            _whole_run, root, cfg_json, str(out_path), overwrite, key=f"fluidnerf-run-{token}", pure=False
        ).result()
        warn(report.get("warnings") or [])
        return open_run(out_path)
    plan = json.loads(_ext.window_plan(scene, cfg_json))
    n = len(plan["windows"])
    futures = []
    for k in range(n):
        after = [futures[k - 1]] if plan["warm_start"] and k > 0 else []
        futures.append(
            client.submit(
                train_window,
                root,
                cfg_json,
                str(out_path),
                k,
                *after,
                key=f"fluidnerf-window-{k:03d}-{token}",
                pure=False,
            )
        )
    for future in as_completed(futures):
        outcome = future.result()
        warn(outcome.get("warnings") or [])
        if callback is not None:
            callback({"kind": "window_finished", "window": outcome["index"], "windows": n, **outcome})
    report = client.submit(
        finish, root, cfg_json, str(out_path), *futures, key=f"fluidnerf-finish-{token}", pure=False
    ).result()
    warn(report.get("warnings") or [])
    return open_run(out_path)
