"""Shared fixtures: tiny synthetic scenes (made in code, seconds to build) and the CLI binary."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

import fluidnerf

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def static_scene(tmp_path_factory) -> fluidnerf.Scene:
    """A jet seen by 8 cameras of 20² px (one held out), truth 20³."""
    folder = tmp_path_factory.mktemp("static") / "scene"
    return fluidnerf.synth(
        folder,
        "demo",
        resolution=20,
        lens={"resolution": [20, 20]},
        rig={"layout": {"count": 8}, "holdout": [3]},
    )


@pytest.fixture(scope="session")
def tr_scene(tmp_path_factory) -> fluidnerf.Scene:
    """A starting jet at 5 times seen by 5 cameras of 16² px: 4 windows of 2 frames."""
    folder = tmp_path_factory.mktemp("tr") / "scene"
    return fluidnerf.synth(
        folder,
        "jet-tr60",
        resolution=12,
        times=[14.0, 14.5, 15.0, 15.5, 16.0],
        lens={"resolution": [16, 16]},
        rig={"layout": {"count": 5}, "subset": {"every": 1, "first": None, "offset": 0}},
        image={"model": "pinhole"},
    )


@pytest.fixture(scope="session")
def tr_holdout_scene(tmp_path_factory) -> fluidnerf.Scene:
    """A starting jet at 4 times seen by 5 cameras of 16² px, camera 4 held out at every time."""
    folder = tmp_path_factory.mktemp("tr-holdout") / "scene"
    return fluidnerf.synth(
        folder,
        "jet-tr60",
        resolution=12,
        times=[14.0, 14.5, 15.0, 15.5],
        lens={"resolution": [16, 16]},
        rig={"layout": {"count": 5}, "holdout": [4]},
        image={"model": "pinhole"},
    )


@pytest.fixture(scope="session")
def cli() -> str:
    """The `fluidnerf` binary: $FLUIDNERF_BIN, else the workspace's release build."""
    path = os.environ.get("FLUIDNERF_BIN") or str(REPO / "target" / "release" / "fluidnerf")
    if not Path(path).is_file():
        found = shutil.which("fluidnerf")
        if found is None:
            pytest.fail(f"no fluidnerf binary at {path}: run `cargo build --release` (scripts/test does)")
        path = found
    return path


# Settings of the tiny time-resolved runs: tr-fast, windows of 2 frames overlapping by 1.
TR_METHOD = {
    "name": "tr-fast",
    "field": {"hash-grid": {"levels": 4, "log2_table_size": 12, "max_resolution": 32}},
    "windows": {"frames": 2, "overlap": 1, "warm_start": True},
    "train": {"rays_per_image": 48, "coarse_samples": 12},
}
TR_OPTIONS = {"resolution": 10, "stopping": {"max_iterations": 8}, "checkpoint_every": 0}


def look_at(centre, target, up):
    """A world_from_camera pose with OpenCV axes (x right, y down, z forward)."""
    import numpy as np

    centre, target, up = (np.asarray(v, dtype=float) for v in (centre, target, up))
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, centre
    return m


def ring(n: int, radius: float = 60.0, size: int = 16, focal: float = 30.0):
    """K (n, 3, 3) and world_from_camera (n, 4, 4) of n cameras on a ring about y, looking at 0."""
    import numpy as np

    angles = np.arange(n) * 2 * np.pi / n
    poses = np.stack(
        [look_at([radius * np.cos(a), 3.0, radius * np.sin(a)], [0, 0, 0], [0, 1, 0]) for a in angles]
    )
    k = np.array([[focal, 0, (size - 1) / 2], [0, focal, (size - 1) / 2], [0, 0, 1.0]])
    return np.tile(k, (n, 1, 1)), poses


def ticks_while(work) -> tuple[int, float]:
    """Runs `work()` beside a thread that ticks once per 1 ms sleep, and returns how often it
    ticked meanwhile and the seconds `work` took: a call that holds the GIL leaves it near 0."""
    import threading
    import time

    ticks, done = [0], threading.Event()

    def tick():
        while not done.is_set():
            ticks[0] += 1
            time.sleep(0.001)

    ticker = threading.Thread(target=tick)
    ticker.start()
    try:
        time.sleep(0.02)
        before, start = ticks[0], time.perf_counter()
        work()
        return ticks[0] - before, time.perf_counter() - start
    finally:
        done.set()
        ticker.join()
