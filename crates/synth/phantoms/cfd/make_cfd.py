"""Generates the CFD phantoms of `fluidnerf synth`: a buoyant plume and a forced round jet.

Both flows are solved with PhiFlow (incompressible Navier-Stokes without explicit viscosity on
a staggered grid: MacCormack advection of the marker, semi-Lagrangian advection of the
velocity, a conjugate-gradient pressure projection) on a grid of NX x NY x NZ cells of unit
width, with a time step of DT. The flows rise along +y from near the bottom face (y = 0) and
leave through the open top face (y = NY); the other faces are closed walls. The fluid starts
at rest up to a weak, smooth, seeded random velocity field (AMBIENT_RMS) that breaks the
symmetry of the sources.

- plume: a buoyant plume (Boussinesq). A hot spot near the bottom holds the marker c at 1 (its
  rim is modulated by a seeded random azimuthal pattern that drifts from step to step, to break the
  symmetry); the marker pushes the fluid up with the body force (0, G_PRIME * c, 0). The
  marker is both the temperature excess and the smoke: with equal source and equal (numerical)
  diffusivity the two fields are the same (Lewis number 1).
- jet: a forced round jet. Inside a short cylinder on the bottom face (the nozzle) the
  velocity is held at U_JET along +y, with a seeded random perturbation of 10 per cent, and
  the marker at 1; the marker is passive.

Several instants of each are written as float32 `.npy` of shape (nz, ny, nx) (x fastest,
cell-centred, the project's volume convention), clipped to >= 0, with `provenance.json`
beside them (solver, grid, parameters, time step, step numbers, seed, command, licence, and
per-file statistics that the Rust tests check).

Usage: python make_cfd.py [--out DIR] [--seed N]
"""

import argparse
import json
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import phi
from phi.flow import (
    Box,
    CenteredGrid,
    Solve,
    StaggeredGrid,
    advect,
    extrapolation,
    fluid,
    math,
    resample,
    spatial,
    vec,
)
from phiml.backend._numpy_backend import NumPyBackend

# phiml 1.16 packs sparse-matrix indices in the int32 of its index arrays, which overflows
# (cells^2 > 2^31) on grids above ~46k cells while building the pressure matrix. Raveling in
# int64 is all the fix needs; the solver is otherwise unchanged.
_ravel_multi_index = NumPyBackend.ravel_multi_index


def _ravel_multi_index_int64(self, multi_index, shape, mode="undefined"):
    return _ravel_multi_index(self, np.asarray(multi_index, dtype=np.int64), shape, mode)


NumPyBackend.ravel_multi_index = _ravel_multi_index_int64

# Grid (cells of unit width; the Rust side maps one cell to CELL_MM millimetres).
NX, NY, NZ = 48, 72, 48
CELL_MM = 0.5
DT = 2.0
# Instants written: 50 -> 52 and 50 -> 60 are 2 and 10 steps apart (for time-resolved tests);
# 40 is an earlier, less developed instant.
STEPS = (40, 50, 52, 60)

# Plume: hot spot of radius R_SRC centred at height Y_SRC; buoyancy G_PRIME per unit marker.
R_SRC = 4.0
Y_SRC = 5.0
G_PRIME = 0.05
SRC_RIM_MODULATION = 0.35

# Jet: nozzle of diameter D_JET from y = 0 to y = L_NOZZLE, exit speed U_JET.
D_JET = 6.0
L_NOZZLE = 4.0
U_JET = 2.0
JET_PERTURBATION = 0.1

# Ambient disturbance: at rest up to a seeded random, smooth velocity field of this RMS speed
# (cells per unit time), low-pass filtered to wavelengths above AMBIENT_WAVELENGTH cells. It
# breaks the symmetry of the sources, as the draughts of a real laboratory do.
AMBIENT_RMS = 0.02
AMBIENT_WAVELENGTH = 12.0
# The source and nozzle perturbations drift: their azimuthal phases take a random walk of this
# standard deviation (radians) per step, so a pattern persists for several steps.
PHASE_WALK = 0.3

SOLVE = {"method": "CG", "rel_tol": 1e-4, "abs_tol": 1e-4, "max_iterations": 500}

LICENCE = (
    "Data: MIT OR Apache-2.0, as the fluidnerf project. Generated with PhiFlow "
    "(MIT licence, https://github.com/tum-pbs/PhiFlow)."
)


def cell_centres():
    """Cell-centre coordinates as three arrays indexed [x, y, z]."""
    x = np.arange(NX) + 0.5
    y = np.arange(NY) + 0.5
    z = np.arange(NZ) + 0.5
    return np.meshgrid(x, y, z, indexing="ij")


def smooth_step(d, width=1.0):
    """1 inside (d < -width/2), 0 outside, linear across a band of `width` cells."""
    return np.clip(0.5 - d / width, 0.0, 1.0)


class AzimuthalNoise:
    """A random pattern in [-1, 1] of the first `modes` azimuthal Fourier modes whose phases
    drift by a random walk from one step to the next."""

    def __init__(self, rng, modes=4):
        self.rng = rng
        self.amplitude = rng.normal(size=modes) / np.arange(1, modes + 1)
        self.phase = rng.uniform(0, 2 * np.pi, size=modes)

    def step(self, theta):
        self.phase += self.rng.normal(0.0, PHASE_WALK, size=self.phase.shape)
        a = self.amplitude
        pattern = sum(a[m] * np.cos((m + 1) * theta + self.phase[m]) for m in range(len(a)))
        return pattern / max(np.abs(a).sum(), 1e-9)


def ambient_velocity(rng):
    """Three smooth random velocity components indexed [x, y, z], RMS speed AMBIENT_RMS."""
    k = [np.fft.fftfreq(n) for n in (NX, NY, NZ)]
    kx, ky, kz = np.meshgrid(*k, indexing="ij")
    low_pass = np.exp(-0.5 * (kx**2 + ky**2 + kz**2) * AMBIENT_WAVELENGTH**2)
    parts = []
    for _ in range(3):
        u = np.fft.ifftn(np.fft.fftn(rng.normal(size=(NX, NY, NZ))) * low_pass).real
        parts.append(u)
    rms = np.sqrt(np.mean(sum(u**2 for u in parts)))
    return [u * (AMBIENT_RMS / rms) for u in parts]


def grids():
    bounds = Box(x=NX, y=NY, z=NZ)
    wall = extrapolation.ZERO
    v_ext = extrapolation.combine_sides(x=wall, y=(wall, extrapolation.BOUNDARY), z=wall)
    c_ext = extrapolation.combine_sides(x=wall, y=(wall, extrapolation.ZERO_GRADIENT), z=wall)
    marker = CenteredGrid(0, c_ext, bounds, x=NX, y=NY, z=NZ)
    velocity = StaggeredGrid(0, v_ext, bounds, x=NX, y=NY, z=NZ)
    return bounds, marker, velocity


def centred(values, like):
    """A CenteredGrid like `like` holding the numpy array `values` indexed [x, y, z]."""
    return like.with_values(math.tensor(values.astype(np.float32), spatial("x,y,z")))


def simulate(case, seed, on_instant):
    rng = np.random.default_rng(seed)
    _, marker, velocity = grids()
    x, y, z = cell_centres()
    rx, rz = x - NX / 2, z - NZ / 2
    radius = np.hypot(rx, rz)
    theta = np.arctan2(rz, rx)
    if case == "plume":
        dist = np.sqrt(rx**2 + (y - Y_SRC) ** 2 + rz**2)
    else:
        dist = np.maximum(radius - D_JET / 2, y - L_NOZZLE)
    ux, uy, uz = ambient_velocity(rng)
    ambient = sum(
        centred(u, marker) * vec(x=ex, y=ey, z=ez)
        for u, (ex, ey, ez) in ((ux, (1, 0, 0)), (uy, (0, 1, 0)), (uz, (0, 0, 1)))
    )
    velocity, pressure = fluid.make_incompressible(resample(ambient, to=velocity), (), Solve(**SOLVE))
    azimuthal = AzimuthalNoise(rng)
    for step in range(1, max(STEPS) + 1):
        noise = azimuthal.step(theta)
        if case == "plume":
            source = smooth_step(dist - R_SRC * (1.0 + SRC_RIM_MODULATION * 0.5 * (noise - 1.0)))
        else:
            source = smooth_step(dist)
        source_grid = centred(source, marker)
        marker = advect.mac_cormack(marker, velocity, DT)
        marker = marker * (1 - source_grid) + source_grid
        velocity = advect.semi_lagrangian(velocity, velocity, DT)
        if case == "plume":
            velocity = velocity + resample(marker * vec(x=0, y=G_PRIME * DT, z=0), to=velocity)
        else:
            # Exit velocity: U along +y with a random pulsation, plus a radial velocity of
            # random azimuthal modes (helical and flapping disturbances of the shear layer).
            u_exit = U_JET * (1.0 + JET_PERTURBATION * rng.normal())
            radial = JET_PERTURBATION * U_JET * noise * source
            exit_x = centred(radial * np.cos(theta), marker) * vec(x=1, y=0, z=0)
            exit_y = centred(source * u_exit, marker) * vec(x=0, y=1, z=0)
            exit_z = centred(radial * np.sin(theta), marker) * vec(x=0, y=0, z=1)
            mask = resample(source_grid * vec(x=1, y=1, z=1), to=velocity)
            velocity = velocity * (1 - mask) + resample(exit_x + exit_y + exit_z, to=velocity)
        velocity, pressure = fluid.make_incompressible(velocity, (), Solve(x0=pressure, **SOLVE))
        if step in STEPS:
            # numpy("z,y,x") is a transposed view; the files must be C-ordered (x fastest).
            values = np.ascontiguousarray(marker.values.numpy("z,y,x"), dtype=np.float32)
            on_instant(step, np.clip(values, 0.0, None))


def fnv1a64(data: bytes) -> int:
    """FNV-1a 64-bit hash of `data` (the Rust tests recompute it over the same bytes)."""
    h = 0xCBF29CE484222325
    for b in data:
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return h


def statistics(vol):
    """Sum, maximum and marker-weighted centroid (cell indices x, y, z) of a (nz, ny, nx) array."""
    v = vol.astype(np.float64)
    total = v.sum()
    k, j, i = np.meshgrid(*(np.arange(n) for n in vol.shape), indexing="ij")
    centroid = [float((v * a).sum() / total) for a in (i, j, k)]
    fnv = fnv1a64(np.ascontiguousarray(vol, dtype="<f4").tobytes())
    return {"sum": float(total), "max": float(v.max()), "centroid_ijk": centroid, "fnv1a64": f"{fnv:016x}"}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    math.seed(args.seed)
    cases = {}
    started = time.time()
    for index, case in enumerate(("plume", "jet")):
        files = []
        t0 = time.time()
        cpu0 = time.process_time()

        def on_instant(step, vol, case=case, files=files, t0=t0):
            name = f"{case}_s{step:04d}.npy"
            np.save(args.out / name, vol)
            files.append(
                {"file": name, "step": step, "time": step * DT, "shape": list(vol.shape), **statistics(vol)}
            )
            print(f"{case}: step {step}, max {vol.max():.3f}, {time.time() - t0:.0f} s", flush=True)

        simulate(case, args.seed + index, on_instant)
        cases[case] = {
            "seed": args.seed + index,
            "cpu_seconds": round(time.process_time() - cpu0, 1),
            "wall_seconds": round(time.time() - t0, 1),
            "instants": files,
        }
    provenance = {
        "description": "CFD phantoms of fluidnerf synth: a buoyant plume and a forced round jet, rising along +y",
        "solver": {
            "name": "PhiFlow",
            "version": phi.__version__,
            "backend": "NumPy " + np.__version__,
            "python": platform.python_version(),
            "scheme": "staggered grid; MacCormack marker advection, semi-Lagrangian velocity advection, "
            "CG pressure projection; no explicit viscosity (numerical dissipation only)",
            "pressure_solve": SOLVE,
        },
        "grid": {
            "cells_xyz": [NX, NY, NZ],
            "cell_width": 1.0,
            "world_cell_mm": CELL_MM,
            "array_shape": [NZ, NY, NX],
            "layout": "float32 .npy, shape (nz, ny, nx), x fastest, cell-centred, clipped to >= 0",
            "boundaries": "walls at x, z faces and at y = 0; open top at y = NY (zero-gradient velocity and marker)",
            "flow_axis": "+y",
        },
        "time_step": DT,
        "ambient_disturbance": {
            "rms_speed_cells_per_time": AMBIENT_RMS,
            "wavelength_cells": AMBIENT_WAVELENGTH,
        },
        "perturbation_phase_walk_rad_per_step": PHASE_WALK,
        "steps_saved": list(STEPS),
        "plume": {
            "source": "ball holding the marker at 1",
            "source_radius_cells": R_SRC,
            "source_centre_cells": [NX / 2, Y_SRC, NZ / 2],
            "source_rim_modulation": SRC_RIM_MODULATION,
            "buoyancy": "Boussinesq body force (0, g' c, 0) on the velocity",
            "g_prime_cells_per_time2": G_PRIME,
            **cases["plume"],
        },
        "jet": {
            "nozzle": "cylinder on the bottom face holding velocity (0, U, 0) and the marker at 1",
            "nozzle_diameter_cells": D_JET,
            "nozzle_length_cells": L_NOZZLE,
            "nozzle_centre_xz_cells": [NX / 2, NZ / 2],
            "exit_speed_cells_per_time": U_JET,
            "random_perturbation": JET_PERTURBATION,
            **cases["jet"],
        },
        "seed": args.seed,
        "command": shlex.join(["python", "make_cfd.py", *sys.argv[1:]]),
        "working_directory": "crates/synth/phantoms/cfd",
        "total_cpu_seconds": round(time.process_time(), 1),
        "total_wall_seconds": round(time.time() - started, 1),
        "licence": LICENCE,
    }
    text = json.dumps(provenance, indent=2) + "\n"
    (args.out / "provenance.json").write_text(text)
    print(f"wrote {args.out} in {time.time() - started:.0f} s")


if __name__ == "__main__":
    main()
