"""fluidnerf: flow tomography from calibrated camera images.

Reconstructs the 3D (and 4D) scalar field of a glowing flow — smoke, dye,
chemiluminescence, a flame — from a handful of calibrated camera images, with FluidNeRF
(a neural field trained through a line-integral renderer), grid fields, and the classical
algebraic methods (ASART, ART, SART, MART, SMART, MLEM, TV and Tikhonov regularised SART).

Every reconstruction goes through the same library pipeline, with the same settings
(``RunConfig``), as the ``fluidnerf`` command line, and writes the same run folder::

    import fluidnerf
    scene = fluidnerf.synth("jet", "demo", resolution=32, lens={"resolution": [32, 32]})
    run = fluidnerf.reconstruct(scene, "asart", "run-asart", resolution=32)
    print(run.report["final_nrmse"], run.volume.shape)

Conventions (those of the Rust core): world units of the scene (usually mm); cameras with
OpenCV axes (x right, y down, z forward) and pixel centres at integer coordinates; poses as
``world_from_camera`` (camera to world) 4 × 4 matrices; volumes as ``(nz, ny, nx)`` float32
arrays of cell-centred voxels filling the box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``.

``fluidnerf.dask`` runs long time-resolved recordings window by window on a Dask cluster.
"""

from ._api import (
    Camera,
    FluidNerfError,
    FluidNerfWarning,
    Run,
    Scene,
    back_project,
    build_config,
    forward_project,
    load_scene,
    methods,
    nrmse,
    open_run,
    plan_windows,
    psnr,
    read_colmap,
    read_davis,
    read_metashape,
    read_opencv,
    read_projection,
    read_transforms,
    read_video,
    reconstruct,
    render,
    scene_from_arrays,
    ssim,
    synth,
    synth_presets,
    window_plan,
)
from ._fluidnerf import __version__

__all__ = [
    "Camera",
    "FluidNerfError",
    "FluidNerfWarning",
    "Run",
    "Scene",
    "__version__",
    "back_project",
    "build_config",
    "forward_project",
    "load_scene",
    "methods",
    "nrmse",
    "open_run",
    "plan_windows",
    "psnr",
    "read_colmap",
    "read_davis",
    "read_metashape",
    "read_opencv",
    "read_projection",
    "read_transforms",
    "read_video",
    "reconstruct",
    "render",
    "scene_from_arrays",
    "ssim",
    "synth",
    "synth_presets",
    "window_plan",
]
