"""The documented Python API over the extension module ``fluidnerf._fluidnerf``."""

from __future__ import annotations

import copy
import json
import math
import operator
import os
import shutil
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional, Union

import numpy as np

from . import _fluidnerf as _ext
from ._fluidnerf import FluidNerfError, Scene

#: The method of a run given neither a method nor a configuration, as ``fluidnerf
#: reconstruct`` without ``--method``: a voxel reconstruction first, then the grid field
#: started from it, the most accurate method in every comparison of ``docs/claims.md``; for
#: a scene whose frames hold several times, :data:`DEFAULT_TIME_RESOLVED_METHOD`.
DEFAULT_METHOD = "hybrid"
DEFAULT_TIME_RESOLVED_METHOD = "tr-fast"


def _default_method(scene: Scene | PathLike) -> str:
    times = {t for t in _as_scene(scene).times if t is not None}
    return DEFAULT_TIME_RESOLVED_METHOD if len(times) > 1 else DEFAULT_METHOD


PathLike = Union[str, "os.PathLike[str]"]
Callback = Callable[[dict], Optional[bool]]


def _plain(value: Any, what: str, key: str = "") -> Any:
    """Settings ``value`` in JSON's types: NumPy numbers and arrays become numbers and lists,
    paths strings. A NaN or an infinity (JSON has neither), an integer beyond 64 bits or any
    other object is refused, naming ``what`` and the key."""
    at = f"{what}: at `{key}`" if key else what
    if isinstance(value, dict):
        return {k: _plain(v, what, f"{key}.{k}" if key else str(k)) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return [_plain(v, what, f"{key}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, float) and not math.isfinite(value):
        raise FluidNerfError(f"{at}: {value} is not a finite number")
    if isinstance(value, int) and not isinstance(value, bool) and not -(2**63) <= value <= 2**64 - 1:
        # JSON would carry it, but the library reads such an integer as a float, and its
        # refusal spoke of "floating point 1.8446744073709552e+19" for the integer given.
        raise FluidNerfError(f"{at}: {value} is beyond the 64-bit integers settings hold")
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    raise TypeError(f"{at}: expected a number, string, list or dict, got {type(value).__name__} {value!r}")


def _dumps(value: Any, what: str) -> str:
    """``value`` (settings) as JSON text; see :func:`_plain`."""
    return json.dumps(_plain(value, what))


#: What arrays of NumPy's other kinds hold, named when one is given for numbers.
_NOT_NUMBERS = {"U": "strings", "S": "strings", "M": "dates", "m": "durations", "V": "structured records"}


def _numbers(value: Any, dtype: type, name: str, shape: str = "") -> np.ndarray:
    """``value`` as a C-ordered array of ``dtype``; complex numbers, strings, ragged lists and
    other objects that are no array of real numbers are refused naming the argument (NumPy's
    own messages name none, and a cast to a real type silently drops imaginary parts)."""
    if value is None:
        # NumPy reads None as NaN.
        raise TypeError(f"{name}: expected an array of numbers{shape}, got None")
    if isinstance(value, np.ma.MaskedArray) and np.ma.count_masked(value):
        # np.asarray drops the mask: the values under it were computed with as if given.
        raise FluidNerfError(
            f"{name}: a masked array with {np.ma.count_masked(value)} masked element(s), whose mask would be "
            f"ignored: give a plain array{shape}, the masked elements filled (e.g. a.filled(0))"
        )
    try:
        complex_numbers = np.iscomplexobj(value)
        # Not np.ascontiguousarray, which makes a 0-d array (a single number) one of shape (1,).
        given = None if complex_numbers else np.asarray(value)
        # A mask given for an image or a volume would pass for one of zeros and ones.
        if given is not None and given.dtype == np.bool_:
            raise TypeError(f"{name}: expected an array of numbers{shape}, got booleans")
        # NumPy casts strings of digits, dates and durations to numbers without a word: "12"
        # compared with "13" gave an NRMSE, dates one of days since 1970.
        other = None if given is None else _NOT_NUMBERS.get(given.dtype.kind)
        if (
            given is not None
            and given.dtype.kind == "O"
            and any(isinstance(v, (str, bytes)) for v in given.flat)
        ):
            other = "strings"
        if other is not None:
            raise TypeError(f"{name}: expected an array of numbers{shape}, got {other} ({given.dtype})")
        if given is not None and given.dtype.kind == "O":
            # NumPy casts None to NaN: [1.0, None] was refused as "not finite (NaN)", a value
            # nobody gave.
            missing = next((i for i, v in enumerate(given.flat) if v is None), None)
            if missing is not None:
                raise TypeError(
                    f"{name}: element {missing} (flat index, C order) is None; expected an array of numbers{shape}"
                )
            # A list of Python integers is an array of objects: one beyond the type was cast
            # to an infinity (refused as "not finite (inf)", a value nobody gave), or beyond
            # float64 raised a bare "OverflowError: int too large to convert to float".
            largest = float(np.finfo(dtype).max)
            for i, v in enumerate(given.flat):
                if isinstance(v, int) and not isinstance(v, bool) and abs(v) > largest:
                    _beyond(name, i, f"an integer of {len(str(abs(v)))} digits", np.dtype(dtype))
        # A value beyond the type is found below, not left to NumPy's warning.
        with np.errstate(over="ignore"):
            a = None if given is None else given.astype(dtype, copy=False)
    except FluidNerfError:
        raise
    except (TypeError, ValueError) as e:
        if "got booleans" in str(e) or "expected an array of numbers" in str(e):
            raise
        raise TypeError(f"{name}: expected an array of numbers{shape}: {e}") from None
    if a is None:
        raise TypeError(f"{name}: expected real numbers{shape}, got complex ones")
    if a.dtype != given.dtype and given.dtype.kind == "f":
        # Cast to an infinity, it was refused as "not finite (inf)", a value nobody gave.
        beyond = np.flatnonzero(np.isinf(a) & np.isfinite(given))
        if beyond.size:
            i = int(beyond[0])
            _beyond(name, i, repr(float(given.flat[i])), a.dtype)
    return a if a.flags.c_contiguous else np.ascontiguousarray(a)


def _beyond(name: str, i: int, shown: str, dtype: np.dtype) -> None:
    """Refuses element ``i`` of the argument ``name``, ``shown``, as beyond the values of
    ``dtype``."""
    raise FluidNerfError(
        f"{name}: element {i} (flat index, C order), {shown}, is beyond the "
        f"{dtype} values it is computed in (at most {str(np.finfo(dtype).max)} in magnitude)"
    )


def _given(value: Any, a: np.ndarray) -> str:
    """What was given as the array ``a``, for a message: its shape, or a single number as
    itself."""
    if a.ndim == 0 and not isinstance(value, np.ndarray):
        shown = value.item() if isinstance(value, np.generic) else value
        return f"{type(value).__name__} {shown!r}, which is no array"
    return f"an array of shape {a.shape}"


def _array(value: Any, dtype: type, name: str, shape: str) -> np.ndarray:
    """``value`` as a C-ordered array of ``dtype`` with as many dimensions as ``shape`` (e.g.
    ``"(N, 3, 3)"``) names; anything else is refused naming the argument and the shape."""
    a = _numbers(value, dtype, name, f" of shape {shape}")
    if a.ndim != len([side for side in shape.strip("()").split(",") if side.strip()]):
        raise FluidNerfError(f"{name}: expected shape {shape}, got {_given(value, a)}")
    return a


__all__ = [
    "Camera",
    "FluidNerfError",
    "FluidNerfWarning",
    "Run",
    "Scene",
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


# ---------------------------------------------------------------------------------------------
# Scenes


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera read from a calibration file.

    ``K`` is the 3 × 3 intrinsic matrix with pixel centres at integer coordinates (OpenCV),
    ``world_from_camera`` the 4 × 4 camera-to-world pose with OpenCV camera axes (x right,
    y down, z forward), ``distortion`` OpenCV's coefficients ``(k1, k2, p1, p2, k3[, k4, k5,
    k6])`` and ``size`` the image ``(width, height)`` in pixels.

    A camera is a value: its matrices are read-only float64 arrays, two cameras are equal
    when every field is, and a camera can be hashed (kept in a set, used as a dict key).
    """

    name: str
    K: np.ndarray
    world_from_camera: np.ndarray
    distortion: tuple[float, ...]
    size: tuple[int, int]

    def __post_init__(self) -> None:
        # The generated comparison compared the arrays as tuples' items, which raised NumPy's
        # "truth value of an array ... is ambiguous" for any two cameras (and so `in`), and
        # the hash refused them as unhashable; a frozen camera's matrices could be written.
        for field, shape in (("K", (3, 3)), ("world_from_camera", (4, 4))):
            a = np.array(_numbers(getattr(self, field), np.float64, field, f" of shape {shape}"))
            if a.shape != shape:
                raise FluidNerfError(
                    f"{field}: expected shape {shape}, got {_given(getattr(self, field), a)}"
                )
            a.setflags(write=False)
            object.__setattr__(self, field, a)
        object.__setattr__(self, "distortion", tuple(float(d) for d in self.distortion))
        object.__setattr__(self, "size", tuple(int(v) for v in self.size))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return (
            (self.name, self.distortion, self.size) == (other.name, other.distortion, other.size)
            and np.array_equal(self.K, other.K)
            and np.array_equal(self.world_from_camera, other.world_from_camera)
        )

    def __hash__(self) -> int:
        # Values, not bytes: 0.0 and -0.0 are equal, and hash alike.
        return hash(
            (self.name, tuple(self.K.ravel().tolist()), tuple(self.world_from_camera.ravel().tolist()))
            + (self.distortion, self.size)
        )


def _path(value: Any, name: str, expected: str = "a path (a string or os.PathLike)") -> str:
    """``value`` (a string or path) as a string; anything else is refused naming ``name``
    (``os.fspath``'s own message names no argument)."""
    if not isinstance(value, (str, bytes, os.PathLike)):
        raise TypeError(f"{name}: expected {expected}, got {type(value).__name__} {value!r}")
    path = os.fsdecode(os.fspath(value))
    if not path:
        # An empty string (an unset variable, say) stood for the current folder: synth wrote
        # its scene there past the check for a folder holding files, and a run wrote into it.
        raise FluidNerfError(f"{name}: the path is empty; name a file or folder ('.' for the current folder)")
    return path


def _string(value: Any, name: str) -> str:
    """``value``, a string; anything else is refused naming ``name`` (the extension's own
    message, "'int' object cannot be converted to 'PyString'", names no type expected)."""
    if not isinstance(value, str):
        raise TypeError(f"{name}: expected a string, got {type(value).__name__} {value!r}")
    return value


def _boolean(value: Any, name: str) -> bool:
    """``value``, True or False (a NumPy boolean too: a flag read from an array); anything
    else (``1``, ``"no"``) is refused naming ``name``."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name}: expected True or False, got {type(value).__name__} {value!r}")
    return bool(value)


def load_scene(folder: PathLike) -> Scene:
    """Reads and validates the scene in ``folder`` (a folder with ``transforms.json``, or the file)."""
    return Scene.load(_path(folder, "folder"))


def _sequence(value: Any, name: str, expected: str) -> Any:
    """``value``, a sequence with one entry per frame; a string, a mapping, a set, or an
    object that is no sequence at all (``holdout=5``, which raised a bare "'int' object is
    not iterable") is refused naming the argument and ``expected``."""
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{name}: expected {expected}, one per frame, got the string {value!r}")
    zero_d = isinstance(value, np.ndarray) and value.ndim == 0
    if zero_d or isinstance(value, (dict, set, frozenset)) or not hasattr(value, "__iter__"):
        raise TypeError(f"{name}: expected {expected}, one per frame, got {type(value).__name__} {value!r}")
    return value


def _flags(value: Any, name: str) -> list[bool]:
    """``value`` as a list of booleans (``True``/``False``, NumPy booleans, or the integers 0
    and 1); a string, any other object or element is refused naming the argument."""
    flags = []
    for i, v in enumerate(_sequence(value, name, "a sequence of booleans")):
        if isinstance(v, (bool, np.bool_)) or (isinstance(v, (int, np.integer)) and v in (0, 1)):
            flags.append(bool(v))
        else:
            raise TypeError(f"{name}[{i}]: expected a boolean, got {type(v).__name__} {v!r}")
    return flags


def _names(value: Any, name: str) -> list[str | None]:
    """``value`` as a list of camera names (strings, or None for a frame without one); a
    string, any other object or element is refused naming the argument (the extension's
    messages, "Can't extract `str` to `Vec`", named no type expected)."""
    names: list[str | None] = []
    for i, v in enumerate(_sequence(value, name, "a sequence of camera names (strings or None)")):
        if v is not None and not isinstance(v, str):
            raise TypeError(
                f"{name}[{i}]: expected a camera name (a string) or None, got {type(v).__name__} {v!r}"
            )
        names.append(None if v is None else str(v))
    return names


def _distortion(value: Any) -> np.ndarray:
    """The distortion coefficients ``(N, 4|5|8)``; one row ``(4|5|8,)`` is read as ``(1, ...)``."""
    a = _numbers(value, np.float64, "distortion", " of shape (N, 4|5|8)")
    # A single number is refused as given (np.atleast_2d made it one row of one coefficient).
    return _array(value if a.ndim == 0 else np.atleast_2d(a), np.float64, "distortion", "(N, 4|5|8)")


def scene_from_arrays(
    K: np.ndarray,
    world_from_camera: np.ndarray,
    images: np.ndarray,
    aabb: np.ndarray,
    *,
    times: np.ndarray | None = None,
    distortion: np.ndarray | None = None,
    holdout: list[bool] | None = None,
    names: list[str | None] | None = None,
    units: str = "mm",
    intensity_scale: float = 1.0,
) -> Scene:
    """Builds a scene from arrays; it lives in memory until ``scene.save(folder)``.

    Shapes and conventions (those of the Rust core):

    - ``K``: ``(N, 3, 3)`` intrinsics, pixel centres at integer coordinates (OpenCV; a
      centred principal point of a ``W``-wide image is ``cx = (W - 1) / 2``).
    - ``world_from_camera``: ``(N, 4, 4)`` camera-to-world poses, OpenCV camera axes
      (x right, y down, z forward). Invert a world-to-camera ``[R | t]`` first.
    - ``images``: ``(N, H, W)`` linear pixel values, ``pixel = intensity_scale × ∫E ds``.
    - ``aabb``: ``(2, 3)``, ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` in world units.
    - ``times``: ``(N,)`` frame times for time-resolved recordings (None, or None for every
      frame as ``Scene.times`` gives them, for a static scene); ``distortion``:
      ``(N, 4|5|8)`` OpenCV coefficients; ``holdout``: frames kept out of training.

    The scene is checked as a scene read from a folder is (every camera outside the box and
    seeing it, a camera name once per instant, ...), naming the frame.
    """
    f64 = np.float64
    if isinstance(times, (list, tuple)) and times and all(t is None for t in times):
        # As Scene.times gives them for a static scene (None for every frame): no times, not
        # frames at the time NaN.
        times = None
    pixels = _array(images, np.float32, "images", "(N, H, W)")
    if pixels.shape[0] > 0 and 0 in pixels.shape[1:]:
        # Refused here, where it is the images' problem: the scene blamed the intrinsics.
        raise FluidNerfError(
            f"images: each image needs at least one pixel, got shape {pixels.shape} (N, H, W)"
        )
    return Scene.from_arrays(
        _array(K, f64, "K", "(N, 3, 3)"),
        _array(world_from_camera, f64, "world_from_camera", "(N, 4, 4)"),
        pixels,
        _array(aabb, f64, "aabb", "(2, 3)"),
        times=None if times is None else _array(times, f64, "times", "(N,)"),
        distortion=None if distortion is None else _distortion(distortion),
        holdout=None if holdout is None else _flags(holdout, "holdout"),
        names=None if names is None else _names(names, "names"),
        units=_string(units, "units"),
        intensity_scale=_real(intensity_scale, "intensity_scale"),
    )


def read_transforms(path: PathLike, aabb: np.ndarray | None = None) -> Scene:
    """Reads a ``transforms.json`` of nerfstudio, instant-ngp or a Blender/NeRF exporter as a
    scene; ``aabb`` ``(2, 3)`` gives the box when the file has none. A box the file does not
    hold makes a scene of its own, in memory until saved (``reconstruct`` saves it into the
    run's ``scene/``, as one built from arrays); it is refused for a file with ground truth,
    which fills the file's box."""
    box = None if aabb is None else _array(aabb, np.float64, "aabb", "(2, 3)")
    return _ext.read_transforms(_path(path, "path"), box)


def _cameras(raw: list) -> list[Camera]:
    return [Camera(n, k, p, tuple(d), (int(s[0]), int(s[1]))) for n, k, p, d, s in raw]


def read_opencv(path: PathLike) -> list[Camera]:
    """The cameras of an OpenCV calibration (``cv::FileStorage`` YAML/XML/JSON file, a
    stereo pair's files, or a folder of them), as ``fluidnerf import --opencv`` reads it."""
    return _cameras(_ext.read_opencv(_path(path, "path")))


def read_colmap(folder: PathLike) -> list[Camera]:
    """The images of a COLMAP model (text or binary) as cameras named by image file, with
    COLMAP's pixel centres converted."""
    return _cameras(_ext.read_colmap(_path(folder, "folder")))


def read_metashape(path: PathLike, skip_unaligned: bool = False) -> list[Camera]:
    """The enabled, aligned cameras of an Agisoft Metashape camera export (``.xml``) named by
    label, as ``fluidnerf import --metashape`` reads them: poses in the chunk's coordinate
    system (metres) when the file gives the chunk's transform. Cameras the file has not
    aligned are refused, named, unless ``skip_unaligned``; disabled cameras are left out."""
    skip = _boolean(skip_unaligned, "skip_unaligned")
    return _cameras(_ext.read_metashape(_path(path, "path"), skip))


def _size(value: Any, name: str) -> tuple[int, int]:
    """An image size ``(width, height)`` of positive integers; anything else is refused
    naming ``name``. A NumPy array of two integers (a row of ``Scene.camera_arrays()``'s
    sizes) is one."""
    given = value
    if isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype.kind in "iu":
        value = value.tolist()
    if (
        not isinstance(value, (tuple, list))
        or len(value) != 2
        or not all(isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)) for v in value)
        or not all(0 < int(v) < 2**31 for v in value)
    ):
        raise FluidNerfError(
            f"{name}: expected an image size (width, height) of positive integers, got {given!r}"
        )
    return int(value[0]), int(value[1])


def read_projection(
    path: PathLike,
    image_size: tuple[int, int] | dict[str, tuple[int, int]],
    bottom_left_origin: bool = False,
) -> list[Camera]:
    """The cameras of 3 × 4 projection matrices or 11 DLT coefficients in text files (one
    camera's matrix, or one camera per column), as ``fluidnerf import --projection`` reads
    them: each matrix split into the pinhole's ``K`` and pose, without distortion. A matrix
    holds no image size: ``image_size`` gives it, ``(width, height)`` for every camera or a dict
    by camera name. ``bottom_left_origin``: the matrices count v up from the image's bottom
    edge (DLTdv, Easy-WAND), and each v is taken as the height − v."""
    bottom_left_origin = _boolean(bottom_left_origin, "bottom_left_origin")
    if isinstance(image_size, dict):
        if not all(isinstance(k, str) for k in image_size):
            raise TypeError("image_size: a dict's keys are camera names (strings)")
        sizes = {k: _size(v, f"image_size[{k!r}]") for k, v in image_size.items()}
        size = None
    else:
        sizes, size = {}, _size(image_size, "image_size")
    raw = _ext.read_projection(_path(path, "path"), size, sizes, bool(bottom_left_origin))
    return _cameras(raw)


def read_video(
    path: PathLike,
    *,
    start: int = 0,
    end: int | None = None,
    every: int = 1,
    time_offset: float = 0.0,
    range: str = "auto",
    linearisation: str = "linear",
) -> tuple[np.ndarray, np.ndarray, dict]:
    """The frames of one camera's recording, decoded as ``fluidnerf import`` decodes them:
    MJPEG AVI, Phantom ``.cine`` and Photron ``.mraw`` (its ``.cihx``/``.cih`` header beside
    it) without ffmpeg, other formats through ``ffmpeg``.

    Keeps frames ``start`` to ``end - 1`` (0-based; ``end=None``: to the last), every
    ``every``-th of them. Returns ``(frames, times, info)``: ``frames`` of shape
    ``(n, height, width)`` and dtype float32 (8-bit video on the 0–255 scale, range-mapped by
    ``range`` — ``"auto"``, ``"full"`` or ``"limited"`` — and linearised by ``linearisation``
    — ``"linear"``, ``"srgb"`` or a gamma such as ``"2.2"``; a cine's or MRAW's frames as the
    sensor's linear counts), ``times`` in seconds (float64, plus ``time_offset``), and
    ``info``, how the file was read (decoder, size, frame rate, frames in the file and kept,
    range and where it came from, clipped pixels), as ``import.json`` records it."""
    start = _integer(start, "start")
    every = _integer(every, "every")
    if start < 0:
        raise ValueError(f"start: {start} is negative; frames count from 0")
    if every < 1:
        raise ValueError(f"every: {every}; keep every 1st frame or more (every >= 1)")
    if end is not None:
        end = _integer(end, "end")
        if end <= start:
            raise ValueError(f"end: {end} is not after start {start}: the selection is empty")
    for name, value in (("start", start), ("every", every), ("end", end)):
        if value is not None:
            _within_u64(value, name)
    time_offset = _real(time_offset, "time_offset")
    if not np.isfinite(time_offset):
        raise ValueError(f"time_offset: {time_offset} is not a finite number of seconds")
    range, linearisation = _string(range, "range"), _string(linearisation, "linearisation")
    frames, times, info = _ext.read_video(
        _path(path, "path"), start, end, every, time_offset, range, linearisation
    )
    return frames, times, json.loads(info)


def read_davis(path: PathLike) -> tuple[np.ndarray, list[str | None], dict[str, str]]:
    """Every frame of a LaVision DaVis image (``.im7``, or the older ``.imx``), as
    ``fluidnerf import`` reads it.

    A DaVis file holds one recorded instant of every camera, one frame per camera and
    exposure. Returns ``(frames, labels, attributes)``: ``frames`` of shape
    ``(n, height, width)`` and dtype float32, the counts as stored (no intensity scale
    applied), row 0 at the top; ``labels``, each frame's camera number and exposure letter from
    its ``CameraName<k>`` attribute (``"1A"``: camera 1, exposure A; ``"2"``: camera 2 of a
    single-exposure recording; ``None`` when the file does not name it); ``attributes``, the
    file's text attributes (``_SCALE_I``, ``AcqTimeSeries0``, ...), the last value of a name
    given twice. Vector fields (``.vc7``), volumes and other buffer kinds are refused."""
    frames, labels, attributes = _ext.read_davis(_path(path, "path"))
    return frames, labels, dict(attributes)


def _as_scene(scene: Scene | PathLike) -> Scene:
    if isinstance(scene, Scene):
        return scene
    return Scene.load(_path(scene, "scene", "a Scene or the path of a scene folder"))


# ---------------------------------------------------------------------------------------------
# Configuration


def _merge(base: dict, patch: dict) -> dict:
    for key, value in patch.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            _merge(base[key], value)
        else:
            base[key] = copy.deepcopy(value)
    return base


def build_config(
    scene: Scene | PathLike,
    method: str | dict | None = None,
    *,
    config: dict | PathLike | None = None,
    preset: str | None = None,
    **options: Any,
) -> dict:
    """The run configuration (``config.json``'s content, a ``RunConfig``) of a run.

    It starts from ``config`` (a dict or a ``config.json`` path, as ``--config``) or from the
    defaults of ``method`` (with ``preset`` for neural methods; ``None``: the configuration's
    method, else ``"hybrid"``, or ``"tr-fast"`` for a scene of several times); ``method`` may
    also be a dict
    such as ``{"name": "asart", "params": {"relaxation": 0.3}}``, merged into the method's
    defaults. Every other keyword is a ``RunConfig`` key (``resolution``, ``seed``,
    ``stopping``, ``checkpoint_every``, ``eval_every``, ``memory_limit_gib``, ``gains``); dicts
    are merged key by key, e.g. ``stopping={"max_iterations": 50}`` or
    ``gains={"mode": "fit"}``. The result is validated by the
    library: an unknown key or a value out of range raises :class:`FluidNerfError` with the
    message ``config.json`` would give.
    """
    # A path is loaded (and so checked) as reconstruct loads it: a configuration of a folder
    # that holds no scene would only fail when run.
    scene = _as_scene(scene)
    root = scene.root
    method_patch: dict = {}
    name: str | None = None
    if isinstance(method, dict):
        method_patch = dict(method)
        name = method_patch.get("name")
    elif method is not None:
        name = method
    if name is not None and not isinstance(name, str):
        raise TypeError(
            f"method: expected a method name (see fluidnerf.methods()) or a dict of its settings, got {method!r}"
        )
    if config is not None:
        if isinstance(config, dict):
            base, source = copy.deepcopy(config), "config"
        elif isinstance(config, (str, bytes, os.PathLike)):
            path = Path(_path(config, "config", "a dict or the path of a config.json"))
            try:
                base, source = json.loads(path.read_text()), str(path)
            except (OSError, ValueError) as e:
                raise FluidNerfError(f"{path}: cannot read the configuration: {e}") from None
        else:
            raise TypeError(
                f"config: expected a dict or the path of a config.json, got {type(config).__name__}"
            )
        if not isinstance(base, dict):
            raise FluidNerfError(f"{source}: the configuration must be an object of settings, got {base!r}")
        # Another fluidnerf file is named for what it is, as --config names it, not by a key.
        other = _ext.other_file_kind(json.dumps(base))
        if other is not None:
            raise FluidNerfError(
                f"{source}: is {other}, not a run's configuration (a run folder's config.json)"
            )
        if not isinstance(base.get("method") or {}, dict):
            raise FluidNerfError(
                f'{source}: at `method`: expected the method\'s settings such as {{"name": "asart"}}, '
                f"got {base['method']!r}"
            )
        written = (base.get("method") or {}).get("name")
        if name is not None and written is not None and name != written:
            raise FluidNerfError(
                f"the configuration was written for method {written}; to run method {name}, leave out config"
            )
        if preset is not None:
            chosen = next((m for m in (written, name) if m is not None), None)
            fresh = json.loads(
                _ext.default_config(
                    str(root or ""), chosen if chosen is not None else _default_method(scene), preset
                )
            )
            # What no preset sets is kept, as MethodConfig::with_preset_kept keeps it for
            # --preset with --config: the start, the held-out times and the frame spacing.
            kept = {
                k: v
                for k, v in (base.get("method") or {}).items()
                if k in ("start", "holdout_times", "time_step")
            }
            base["method"] = _merge(fresh["method"], kept)
    else:
        # An empty name is refused as the unknown method it is, not read as "no method given"
        # (method="" ran the default method, unannounced).
        chosen = name if name is not None else _default_method(scene)
        base = json.loads(_ext.default_config(str(root or ""), chosen, preset))
    # The scene given, also over a configuration's: a scene in memory has no folder yet (""),
    # and reconstruct names the one it saves the scene in.
    base["scene"] = str(Path(root).absolute()) if root is not None else ""
    if method_patch:
        _merge(base["method"], method_patch)
    _merge(base, options)
    text = _dumps(base, "configuration")
    # The window settings given are refused where the command line refuses --window and
    # --overlap: an overlap with no windows to overlap was recorded and ignored.
    windows = method_patch.get("windows")
    # NumPy integers as Python's (a bool is no count: the configuration's check refuses it).
    given = {
        key: int(value)
        for key, value in (windows.items() if isinstance(windows, dict) else ())
        if key in ("frames", "overlap")
        and isinstance(value, (int, np.integer))
        and not isinstance(value, (bool, np.bool_))
        and 0 <= value < 2**64
    }
    if given:
        whose = "the configuration's" if config is not None and preset is None else "the preset's"
        _ext.check_given_windows(scene, text, given.get("frames"), given.get("overlap"), whose)
    return json.loads(_ext.check_config(text))


def window_plan(scene: Scene | PathLike, method: str | dict = "tr-fast", **options: Any) -> dict:
    """The windows a time-resolved run trains, ``{"frame_times", "windows": [[a, b], ...],
    "warm_start"}`` (frames ``a..b``, ``b`` exclusive); options as :func:`build_config`."""
    scene = _as_scene(scene)
    cfg = build_config(scene, method, **options)
    return json.loads(_ext.window_plan(scene, json.dumps(cfg)))


def plan_windows(n_frames: int, window: int, overlap: int) -> list[tuple[int, int]]:
    """Windows of ``window`` frames overlapping by ``overlap`` over ``n_frames`` frames, as
    ``tr-fast`` plans them: ``(first, end)`` frame ranges, ``end`` exclusive."""
    counts = {"n_frames": n_frames, "window": window, "overlap": overlap}
    for name, value in counts.items():
        if _integer(value, name) < 0:
            raise FluidNerfError(f"{name}: must be at least 0, got {value}")
        _within_u64(value, name)
    return _ext.plan_windows(n_frames, window, overlap)


def methods() -> list[tuple[str, str]]:
    """The reconstruction methods ``(name, description)``."""
    return _ext.methods()


def synth_presets() -> list[tuple[str, str]]:
    """The synthetic scene presets ``(name, description)``."""
    return _ext.synth_presets()


# ---------------------------------------------------------------------------------------------
# Runs


class Run:
    """A finished run folder: its volume(s), its trained field, its report and settings."""

    def __init__(self, handle: Any) -> None:
        self._h = handle
        self._volume: np.ndarray | None = None

    def __repr__(self) -> str:
        try:
            r = self.report or {}
        except FluidNerfError:
            # A repr names the object; the refusal is for what is read from it.
            return f"Run({str(self.path)!r}, kind={self.kind!r}, changed on disk since it was opened)"
        return f"Run({str(self.path)!r}, kind={self.kind!r}, method={r.get('method')!r}, status={r.get('status')!r})"

    @property
    def path(self) -> Path:
        """The run folder."""
        return Path(self._h.path)

    @property
    def kind(self) -> str:
        """``"volume"`` (voxel method), ``"field"`` (static neural) or ``"temporal"``."""
        return self._h.kind

    @property
    def report(self) -> dict | None:
        """``report.json`` (the typed ``RunReport``) as a dict; None for folders assembled by hand.
        Read when the run was opened: refused (:class:`FluidNerfError`) once the run's files
        changed on disk, as :attr:`volume` is."""
        text = self._h.report_json
        return None if text is None else json.loads(text)

    @property
    def config(self) -> dict | None:
        """``config.json`` (the ``RunConfig``) as a dict: ``reconstruct(..., config=run.config)``
        reruns it. Read when the run was opened: refused once the run's files changed on disk."""
        text = self._h.config_json
        return None if text is None else json.loads(text)

    @property
    def status(self) -> str | None:
        """``"finished"`` or ``"interrupted"``."""
        r = self.report
        return None if r is None else r.get("status")

    @property
    def aabb(self) -> np.ndarray:
        """The box the results fill, ``(2, 3)``."""
        return self._h.aabb

    @property
    def volume(self) -> np.ndarray:
        """The (first) volume, ``(nz, ny, nx)`` float32, cell-centred, filling :attr:`aabb`.
        Read once and kept, so read-only: ``run.volume.copy()`` is one to change. Refused
        (:class:`FluidNerfError`) once the run's files changed on disk: the volume kept is then
        another run's than the folder's."""
        self._h.check_unchanged("volume")
        if self._volume is None:
            volume = self._h.volume()
            # Kept and given again: a change in place (`run.volume[v < 0] = 0`, or
            # `run.volume -= 1`, which wrote before it failed) was seen by every later
            # `run.volume`, and not by `run.field` or `run.volumes()`, which read the files.
            volume.setflags(write=False)
            self._volume = volume
        return self._volume

    def volumes(self) -> list[tuple[float | None, np.ndarray]]:
        """Every volume with its time (time-resolved runs: one per frame)."""
        return self._h.volumes()

    def field(self, points: np.ndarray, time: float | None = None) -> np.ndarray:
        """The result at world points ``(N, 3)`` (x, y, z) at ``time``: the trained network of
        neural runs (static or of space and time), the volume sampled trilinearly otherwise.
        Returns ``(N,)`` float32; points outside the box give 0. A time-resolved run is sampled
        at ``time`` between its first and last instants (default: the first); a time outside
        them raises :class:`FluidNerfError`; a time held out at an end of the recording is
        warned of (:class:`FluidNerfWarning`: the field repeats its nearest trained instant
        there). Static results are the same at every time: a ``time`` given to one is warned of,
        as the command line does."""
        pts = _array(points, np.float32, "points", "(N, 3)")
        if pts.shape[1] != 3:
            raise FluidNerfError(f"points: expected shape (N, 3), got {pts.shape}")
        # A time that is no number is refused before a static result warns that it is unused.
        t = None if time is None else _real(time, "time")
        if t is not None and not math.isfinite(t):
            raise FluidNerfError(f"time: expected a finite number, got {time!r}")
        if t is not None and self.kind != "temporal":
            _warn(f"time={time} has no effect: {self.path} is a static result, fixed in time")
        values = self._h.field(pts, t)
        note = self._h.held_note(t) if t is not None and self.kind == "temporal" else None
        if note:
            _warn(f"{self.path}: {note}")
        return values

    def score_held_out(
        self, scene: Scene | PathLike | None = None, *, supersample: int = 2, use_volume: bool = False
    ) -> list[dict]:
        """Scores the run on the frames ``scene`` holds out (default: the scene its
        ``config.json`` names), as ``fluidnerf eval`` does: each held-out image as the run
        fitted the others (linearised, background subtracted, flat-fielded, masked, divided by
        the gain the run recorded for it) against the result rendered from that camera with
        ``supersample`` × ``supersample`` rays per pixel. The result is a neural run's trained
        field, or with ``use_volume=True`` the volume it wrote (``eval --use-volume``): to
        compare methods on one output grid, as ``fluidnerf study`` does, score every run with
        ``use_volume=True``. The measure needs no ground truth. Returns one dict per held-out
        frame: ``frame``, ``camera_name``, ``time``, ``pixels``, ``nrmse``, ``psnr_db``,
        ``ssim_global``, ``ssim_windowed``, ``data_range``.

        The run is checked against the scene as ``fluidnerf eval`` checks it, with its messages:
        a run made from another scene, or filling another box, is warned of
        (:class:`FluidNerfWarning`); a time-resolved run is refused a held-out frame without a
        time, or at a time it never trained (stopped before it reached it, or outside its
        instants), and with ``use_volume=True`` one at an instant it wrote no volume of."""
        if scene is None:
            config = self.config
            if config is None:
                raise FluidNerfError(f"{self.path}: records no scene (no config.json); give the scene")
            scene = config["scene"]
        use_volume = _boolean(use_volume, "use_volume")
        supersample = _positive_int(supersample, "supersample")
        return json.loads(self._h.score_held_out(_as_scene(scene), supersample, use_volume, _warn))

    def voxel_centres(self) -> np.ndarray:
        """World coordinates ``(nz, ny, nx, 3)`` of the centres of :attr:`volume`'s voxels."""
        nz, ny, nx = self.volume.shape
        lo, hi = self.aabb
        axes = [lo[i] + (np.arange(n) + 0.5) * (hi[i] - lo[i]) / n for i, n in enumerate((nx, ny, nz))]
        z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
        return np.stack([x, y, z], axis=-1)

    def save(self, folder: PathLike) -> Run:
        """Copies the run folder to ``folder`` (which must not exist, nor lie inside the run's
        folder or under a file) and returns that copy. A run's own scene (one built from arrays, saved in its
        ``scene/``) goes with it, and the copy's settings name the copy's."""
        dest = Path(_path(folder, "folder"))
        if dest.exists():
            raise FluidNerfError(f"{dest}: already exists; choose a new folder")
        file = next((p for p in dest.absolute().parents if p.is_file()), None)
        if file is not None:
            # Refused as the library refuses an output folder there (copytree raised a bare
            # NotADirectoryError).
            raise FluidNerfError(f"{dest}: cannot create the folder, {file} is a file; choose a new folder")
        if self.path.resolve() in dest.resolve().parents:
            # It would be copied into itself, and left among the run's files.
            raise FluidNerfError(
                f"{dest}: lies inside the run's own folder {self.path}; choose a folder outside it"
            )
        # Copied beside the destination and renamed into place when complete: a copy that
        # failed part way (a file that cannot be read, a full disk) left a half run folder at
        # `folder`, which a second attempt then refused as existing.
        made = [p for p in dest.absolute().parents if not p.exists()]
        tmp: Path | None = None
        try:
            dest.absolute().parent.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.absolute().parent))
            staged = tmp / "run"
            shutil.copytree(self.path, staged, ignore=shutil.ignore_patterns(".lock", "*.lock"))
            _rehome_scenes(staged, self.path.resolve(), dest.absolute().resolve())
            os.rename(staged, dest)
        except (OSError, shutil.Error) as e:
            raise FluidNerfError(
                f"{dest}: cannot copy the run {self.path} there: {_copy_problem(e)}"
            ) from None
        finally:
            if tmp is not None:
                shutil.rmtree(tmp, ignore_errors=True)
            if not dest.exists():
                for parent in made:
                    try:
                        parent.rmdir()
                    except OSError:
                        pass
        return open_run(dest)


def _copy_problem(e: BaseException) -> str:
    """What went wrong in a copy: the first file shutil.copytree could not copy and why, or the
    error itself."""
    if isinstance(e, shutil.Error) and e.args and isinstance(e.args[0], list) and e.args[0]:
        src, _, why = e.args[0][0]
        return f"{src}: {why}"
    return str(e)


def _rehome_scenes(copied: Path, src: Path, dest: Path) -> None:
    """Points the settings in the copy ``copied`` of the run ``src`` (its own and its start
    runs') at the copy's scene, ``dest``'s, where they name a scene inside the run's folder (one
    built from arrays, in scene/): the copy's settings read the copy's, not the original's."""
    for path in sorted(copied.rglob("config.json")):
        try:
            cfg = json.loads(path.read_text())
            scene = Path(cfg["scene"])
        except (OSError, ValueError, TypeError, KeyError):
            continue
        if scene.is_absolute() and src in scene.resolve().parents:
            cfg["scene"] = str(dest / scene.resolve().relative_to(src))
            path.write_text(json.dumps(cfg, indent=2) + "\n")


def open_run(folder: PathLike, aabb: np.ndarray | None = None) -> Run:
    """Reads any finished run folder (voxel, static neural or time-resolved). ``aabb``
    ``(2, 3)`` places a bare ``volume.npy`` that has no report; a run that records its box
    (its report, a field's ``model.json``) is refused a box other than its own."""
    box = None if aabb is None else _array(aabb, np.float64, "aabb", "(2, 3)")
    return Run(_ext.open_run(_path(folder, "folder"), box))


def _check_callback(callback: Any) -> None:
    """Refuses a callback that cannot be called before a run starts: called at the first event,
    it would stop the run and leave an interrupted run in its folder."""
    if callback is not None and not callable(callback):
        raise TypeError(f"callback: expected a function of one event dict, got {callback!r}")


class FluidNerfWarning(UserWarning):
    """A run's warning, issued through Python's :mod:`warnings` as it happens (the run also
    keeps it in ``report["warnings"]``)."""


_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__))


def _warn(message: str) -> None:
    """Issues ``message`` as a :class:`FluidNerfWarning` at the first line outside this
    package, the user's call: a warning raised inside a run's callback named the callback's
    line, so neither the location shown nor ``filterwarnings(module=...)`` said whose call it
    was."""
    level = 1
    frame = sys._getframe(0)
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(_PACKAGE_DIR + os.sep):
        frame = frame.f_back
        level += 1
    warnings.warn(message, FluidNerfWarning, stacklevel=level)


def _warning_callback(callback: Callback | None) -> Callback:
    """``callback`` that also issues each ``warning`` event as a :class:`FluidNerfWarning`."""

    def on_event(event: dict) -> bool | None:
        if event["kind"] == "warning":
            _warn(event["message"])
        answer = callback(event) if callback is not None else None
        # A NumPy boolean (a comparison of NumPy numbers) is a boolean: np.False_ did not
        # stop the run, which went on to its last iteration.
        return bool(answer) if isinstance(answer, np.bool_) else answer

    return on_event


def _progress(progress: Any) -> bool | None:
    """``progress`` as True, False or None; any other object is refused naming it (``"no"``
    counted as true, and was then refused as "progress=True needs tqdm")."""
    if progress is None or isinstance(progress, (bool, np.bool_)):
        return None if progress is None else bool(progress)
    raise TypeError(
        f"progress: expected True, False or None (a bar when tqdm is installed), "
        f"got {type(progress).__name__} {progress!r}"
    )


def _progress_callback(callback: Callback | None, progress: bool | None) -> tuple[Callback | None, Any]:
    """The callback given, combined with a tqdm bar when asked (None: when tqdm is installed)."""
    bar_holder: dict = {}
    if progress is None or progress:
        try:
            from tqdm.auto import tqdm
        except ImportError:
            if progress:
                raise FluidNerfError("progress=True needs tqdm: pip install tqdm") from None
            tqdm = None
    else:
        tqdm = None
    if tqdm is None:
        return callback, None

    def on_event(event: dict) -> bool | None:
        kind = event["kind"]
        if kind == "started":
            if "fit" in bar_holder:
                # A fit the time budget ended before its last step.
                bar_holder.pop("fit").close()
            total = event["max_iterations"] * max(event["windows"], 1)
            bar_holder["per_window"] = event["max_iterations"]
            bar_holder["bar"] = tqdm(total=total, desc=event["method"], initial=event["start_iteration"])
        elif kind == "iteration" and "bar" in bar_holder:
            bar = bar_holder["bar"]
            pos = (event["window"] or 0) * bar_holder["per_window"] + event["iteration"]
            bar.update(max(pos - bar.n, 0))
            bar.set_postfix(loss=f"{event['loss']:.3e}", refresh=False)
        elif kind == "start_fit":
            if "fit" not in bar_holder:
                bar_holder["fit"] = tqdm(total=event["steps"], desc="fit to start")
            bar = bar_holder["fit"]
            bar.update(max(event["step"] - bar.n, 0))
            if event["step"] == event["steps"]:
                bar_holder.pop("fit").close()
        elif kind == "writing" and "bar" in bar_holder:
            bar_holder.pop("bar").close()
        return callback(event) if callback is not None else None

    return on_event, bar_holder


class _SavedScene:
    """A scene from arrays that a call saves into ``out/scene`` of the run folder ``out``,
    with what it takes to take that back (see :meth:`take_back`). The folder's own scene until
    then (of a run being replaced or resumed) is moved aside, to ``out/.scene-replaced``, until
    the run writes its configuration. All of it happens under the folder's scene lock
    (``out/.scene.lock``), and a record of the folder's ``config.json`` is kept beside the aside:
    a call killed outright leaves it to the next call or reader of the folder, which puts the
    scene back when the run never wrote its configuration and discards it when it did."""

    def __init__(self, scene: Scene, out: Path, replace: bool):
        self.scene, self.out, self.own = scene, out, out / "scene"
        self.pristine = scene._copy()
        self.made_out = not out.exists()
        # Only a run being replaced or resumed gives up its scene (``replace``); otherwise saving
        # over a scene folder already there is refused.
        self.aside: _ext.SceneAside | None = _ext.SceneAside(os.fspath(out), replace)

    def save(self, force: bool) -> None:
        """Saves the scene into ``out/scene``; a save that fails takes everything back."""
        try:
            self.scene.save(self.own, force=force)
        except BaseException:
            self.take_back()
            raise

    def written(self) -> bool:
        """Whether the run has written its configuration (``config.json``, its first file)."""
        return self.aside is not None and self.aside.written()

    def take_back(self) -> None:
        """When the run was refused before it wrote anything (its ``config.json``): removes the
        saved scene, puts back the scene the folder held (or removes the run folder if the call
        made it), and puts the scene back in memory as it was, so that the call can be made
        again as before and a refused ``--force`` or ``--resume`` leaves the run as it was; the
        command line leaves nothing either. A run that failed later keeps the scene its
        ``config.json`` names, so that it can be resumed."""
        if self.aside is None:
            return
        if self.aside.written():
            self.finish()
            return
        self.aside.take_back()
        self.aside = None
        if self.made_out:
            try:
                self.out.rmdir()
            except OSError:
                pass
        self.scene._restore(self.pristine)

    def finish(self) -> None:
        """The run has started on the saved scene: the scene it replaced goes."""
        if self.aside is not None:
            self.aside.finish()
            self.aside = None

    def release(self) -> None:
        """Leaves the scene set aside (if any) for the next call or reader of the folder to
        settle, by whether the run has written its configuration by then."""
        if self.aside is not None:
            self.aside.release()
            self.aside = None


def reconstruct(
    scene: Scene | PathLike,
    method: str | dict | None = None,
    out: PathLike | None = None,
    *,
    config: dict | PathLike | None = None,
    preset: str | None = None,
    overwrite: str = "refuse",
    callback: Callback | None = None,
    progress: bool | None = None,
    **options: Any,
) -> Run:
    """Reconstructs ``scene`` with ``method`` into the run folder ``out`` through the library
    pipeline (``fluidnerf_pipeline::reconstruct``), exactly as ``fluidnerf reconstruct`` does.
    ``method`` None runs the method of ``config``, or without one ``"hybrid"`` (``"tr-fast"``
    for a scene of several times), as the command line does without ``--method``; with ``overwrite="resume"``
    and no ``config``, the settings of the run in ``out`` (its ``config.json``) are the base.

    ``options`` are ``RunConfig`` keys (see :func:`build_config`), e.g.
    ``reconstruct(scene, "asart", "run", resolution=64, stopping={"rule": "held-out"})``.
    ``out`` None writes into a new temporary folder (kept; see ``run.path``). A scene built
    from arrays is first saved into ``out/scene`` (and removed again, the scene back in memory,
    when the run is refused). ``overwrite`` is ``"refuse"``, ``"force"`` or ``"resume"``
    (``--force``, ``--resume``).

    ``callback(event)`` receives every event as a dict (``kind``: ``started``, ``iteration``,
    ``evaluation``, ``estimate``, ``checkpoint``, ``window_finished``, ``warning``, ``writing``,
    ``start_fit``); returning ``False`` stops the run. A hybrid's voxel start (any ``start`` the run
    makes itself) first reports its own run, from a ``started`` naming the voxel method to its
    ``writing``; then ``start_fit`` events (``step`` of ``steps``) follow the fit of the field to
    that start, before the field's ``started``. ``progress`` (True or False) shows a tqdm bar (None: when tqdm is installed).
    A run's warnings are issued as :class:`FluidNerfWarning` and kept in ``run.report["warnings"]``.
    The GIL is released while the run works. Ctrl-C stops the run cleanly: its results are
    written (``open_run(out)`` reads them) and ``KeyboardInterrupt`` is raised.
    """
    _check_callback(callback)
    progress = _progress(progress)
    if overwrite not in ("refuse", "force", "resume"):
        raise FluidNerfError(f"overwrite: expected 'refuse', 'force' or 'resume', got {overwrite!r}")
    scene = _as_scene(scene)
    given = Path(_path(out, "out")) if out is not None else None
    if overwrite == "resume" and config is None and given is not None and (given / "config.json").is_file():
        # A resumed run continues with the settings it was started with (as --resume).
        config = given / "config.json"
        asked = method.get("name") if isinstance(method, dict) else method
        try:
            written = (json.loads(config.read_text()).get("method") or {}).get("name")
        except (OSError, ValueError, AttributeError):
            written = None  # build_config names what is wrong with the file
        if isinstance(asked, str) and isinstance(written, str) and asked != written:
            raise FluidNerfError(
                f'{given}: holds a run of method {written}, which overwrite="resume" continues; to run '
                f'method {asked}, give another folder or overwrite="force"'
            )
    cfg = build_config(scene, method, config=config, preset=preset, **options)
    # The temporary folder is made once the settings are accepted, and removed again when the
    # run is refused before it writes anything: each refused call left an empty one behind.
    out_path = given if given is not None else Path(tempfile.mkdtemp(prefix="fluidnerf-run-"))
    saved: _SavedScene | None = None
    if scene.root is None:
        # The settings and the folder are checked before the scene is written into it: a
        # refused run leaves it as it was. Resuming continues on the scene given, saved over
        # the run's own.
        _ext.check_run_folder(os.fspath(out_path), overwrite)
        saved = _SavedScene(scene, out_path, replace=overwrite in ("force", "resume"))
        saved.save(force=overwrite in ("force", "resume"))
        cfg["scene"] = str(Path(os.fspath(scene.root)).absolute())
    cb, bars = _progress_callback(_warning_callback(callback), progress)
    try:
        _ext.reconstruct(scene, json.dumps(cfg), os.fspath(out_path), overwrite, cb)
    except FluidNerfError:
        if saved is not None:
            saved.take_back()
        if given is None and not (out_path / "config.json").exists():
            shutil.rmtree(out_path, ignore_errors=True)
        raise
    except BaseException:
        # Ctrl-C: the run wrote its results on the saved scene, or was stopped before it began.
        if saved is not None:
            saved.take_back()
        raise
    finally:
        if bars and "bar" in bars:
            bars.pop("bar").close()
    if saved is not None:
        saved.finish()
    return open_run(out_path)


# ---------------------------------------------------------------------------------------------
# Operators


def _projector(projector: str | dict | None) -> str:
    if projector is None:
        return "{}"
    if isinstance(projector, str):
        return json.dumps({"kind": projector})
    return _dumps(projector, "projector")


def forward_project(
    scene: Scene | PathLike, volume: np.ndarray, projector: str | dict | None = None
) -> np.ndarray | list[np.ndarray]:
    """``A x``: the images every camera of ``scene`` records of ``volume`` ``(nz, ny, nx)``
    (cell-centred, filling the scene's box) through the classical projector of the voxel
    methods, times ``intensity_scale``. ``projector``: ``"auto"`` (default: the voxel methods'
    choice from the voxels' image size), ``"footprint"``, ``"splat"``, ``"ray"``, or a dict of
    the projector settings (``{"kind", "splat_subdivisions", "ray_step"}``; the visual hull's
    keys and ``kept_footprints_mib``, which only reconstructions use, are refused). Returns ``(N, H, W)`` float32 (a list
    when image sizes differ)."""
    vol = _array(volume, np.float32, "volume", "(nz, ny, nx)")
    return _ext.forward_project(_as_scene(scene), vol, _projector(projector))


#: The most voxels a volume of the classical projectors holds (they index voxels in 32 bits).
_MAX_VOXELS = 2**32 - 1


def back_project(
    scene: Scene | PathLike,
    images: np.ndarray | list[np.ndarray],
    shape: tuple[int, int, int],
    projector: str | dict | None = None,
) -> np.ndarray:
    """``Aᵀ y``: the exact adjoint of :func:`forward_project`, images (one per frame) back into
    a volume of ``shape`` ``(nz, ny, nx)``."""
    if isinstance(images, (str, bytes)) or not hasattr(images, "__iter__"):
        raise TypeError(f"images: expected an (N, H, W) array or a list of (H, W) arrays, got {images!r}")
    if isinstance(images, (dict, set, frozenset)):
        # A dict was read by its keys, as images of strings.
        raise TypeError(
            f"images: expected an (N, H, W) array or a list of (H, W) arrays, got {type(images).__name__}"
        )
    if isinstance(images, np.ndarray) and images.ndim != 3:
        # One (H, W) image was read row by row, as H images of one row each.
        raise FluidNerfError(f"images: expected shape (N, H, W), got an array of shape {images.shape}")
    imgs = [_numbers(im, np.float32, f"images[{i}]", " of shape (H, W)") for i, im in enumerate(images)]
    if isinstance(shape, (str, bytes)) or not hasattr(shape, "__len__") or len(shape) != 3:
        raise FluidNerfError(f"shape: expected the volume's three sides (nz, ny, nx), got {shape!r}")
    nz, ny, nx = (_positive_int(n, f"shape[{i}]") for i, n in enumerate(shape))
    if nz * ny * nx > _MAX_VOXELS:
        # Checked here: a side beyond 64 bits is no count the extension can take at all.
        raise FluidNerfError(
            f"shape: {(nz, ny, nx)} makes {nz * ny * nx} voxels, more than the {_MAX_VOXELS} "
            "(2^32 - 1) the projectors hold"
        )
    return _ext.back_project(_as_scene(scene), imgs, (nz, ny, nx), _projector(projector))


def render(
    scene: Scene | PathLike, volume: np.ndarray, step: float | None = None, supersample: int = 1
) -> np.ndarray | list[np.ndarray]:
    """Line integrals of ``volume`` ``(nz, ny, nx)`` (trilinear) through every pixel of the
    scene's cameras, times ``intensity_scale`` (the reference renderer). ``step``: quadrature
    step in world units (None: the box's smallest side / 256; at most 2^20 steps along the
    box's diagonal), ``supersample`` rays per pixel along each axis (1 to 64)."""
    vol = _array(volume, np.float32, "volume", "(nz, ny, nx)")
    step = None if step is None else _real(step, "step")
    return _ext.render(_as_scene(scene), vol, step, _positive_int(supersample, "supersample"))


def _integer(value: Any, name: str) -> int:
    """``value`` as an int; a float (even 2.0) or a bool is refused, not rounded."""
    if isinstance(value, bool):
        raise TypeError(f"{name}: expected an integer, got {value!r}")
    try:
        return operator.index(value)
    except TypeError:
        raise TypeError(f"{name}: expected an integer, got {value!r}") from None


def _real(value: Any, name: str) -> float:
    """``value`` as a float; a string, a bool or another object is refused naming ``name``, and
    an integer beyond the range of floats (Python's bare OverflowError) too."""
    if isinstance(value, (bool, np.bool_)):
        # float(True) is 1.0: step=True rendered with a step of one world unit.
        raise TypeError(f"{name}: expected a number, got {value!r}")
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{name}: expected a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name}: expected a number, got {value!r}") from None
    except OverflowError:
        digits = len(str(abs(int(value))))
        raise FluidNerfError(
            f"{name}: an integer of {digits} digits is beyond the range of floating-point numbers"
        ) from None


def _within_u64(n: int, name: str) -> int:
    """``n``, a count the extension takes as a 64-bit unsigned integer; a larger one raised
    pyo3's bare "OverflowError: int too big to convert", naming no argument."""
    if n > 2**64 - 1:
        raise FluidNerfError(f"{name}: {n} is more than the largest count, 2^64 - 1")
    return n


def _positive_int(value: Any, name: str) -> int:
    """``value`` as an int of at least 1 that fits in 64 bits; a float (even 2.0) or a bool is
    refused, not rounded."""
    n = _integer(value, name)
    if n < 1:
        raise FluidNerfError(f"{name}: must be at least 1, got {n}")
    return _within_u64(n, name)


def _pair(estimate: Any, truth: Any) -> tuple[np.ndarray, np.ndarray]:
    """The two arrays of a metric as float32, each refused naming it when it is no array of
    real numbers."""
    return _numbers(estimate, np.float32, "estimate"), _numbers(truth, np.float32, "truth")


def _data_range(data_range: Any) -> float | None:
    return None if data_range is None else _real(data_range, "data_range")


def nrmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Normalised RMS error: ``‖estimate − truth‖₂ / ‖truth‖₂`` (dissertation Eq. 6.18).

    Both arrays are taken as float32, the type of every volume and image here, as the run
    reports score them (sums in float64): float64 input is rounded first, which shows when
    the differences are below about 10⁻⁷ of the values."""
    return _ext.nrmse(*_pair(estimate, truth))


def psnr(estimate: np.ndarray, truth: np.ndarray, data_range: float | None = None) -> float:
    """PSNR in dB with peak ``data_range`` (None: the truth's max − min, or 1 when the truth is
    constant, so that the metric stays defined: give ``data_range`` then). The arrays are
    taken as float32, as for :func:`nrmse`."""
    return _ext.psnr(*_pair(estimate, truth), _data_range(data_range))


def ssim(
    estimate: np.ndarray, truth: np.ndarray, data_range: float | None = None, window: str = "uniform"
) -> float:
    """SSIM of 2D or 3D arrays: ``window`` ``"uniform"`` (7 wide, as skimage), ``"gaussian"``
    (σ 1.5) or ``"global"`` (one window over everything). ``data_range`` None: the truth's
    max − min, or 1 when the truth is constant (give it then). The arrays are taken as
    float32, as for :func:`nrmse`."""
    return _ext.ssim(*_pair(estimate, truth), _data_range(data_range), _string(window, "window"))


def synth(
    folder: PathLike, preset: str = "demo", *, seed: int | None = None, force: bool = False, **settings: Any
) -> Scene:
    """Synthesises the scene of ``preset`` (see :func:`synth_presets`) into ``folder`` and
    returns it. ``settings`` override the preset's ``SynthSettings`` key by key, e.g.
    ``synth("jet", "jet-tr60", resolution=24, lens={"resolution": [24, 24]})``. As ``fluidnerf
    synth``, it refuses a folder of another kind (a run's, an export's) and, without
    ``force=True``, one that already holds a scene or any other file."""
    if seed is not None:
        settings["seed"] = _integer(seed, "seed")
    return _ext.synth(
        _path(folder, "folder"),
        _string(preset, "preset"),
        _dumps(settings, "synth settings"),
        _boolean(force, "force"),
    )
