//! Throughput of the synthetic generator on the default preset (`planar15`: 256³ jet truth,
//! 256² px cameras): voxelising the jet phantom, then the pinhole and thin-lens image models on
//! the first `CAMERAS` of its 15 cameras (a fixed fraction, so a run takes tens of seconds).
//!
//! Run: `cargo bench --no-run -p fluidnerf-synth`, then the printed executable with `--bench`.

#![allow(clippy::print_stdout)]

use std::time::Instant;

use fluidnerf_core::Volume;
use fluidnerf_synth::image::{pinhole, thin_lens};
use fluidnerf_synth::{preset, Emitters, ImageModel, Phantom, PinholeSettings, ThinLensSettings, DEFAULT_PRESET};

const CAMERAS: usize = 3;

/// CPU time of this process (all threads), from `/proc/self/stat` (utime + stime, in clock
/// ticks of 10 ms); the machine may be shared, so rates per CPU-second are the stable figure.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<f64> = after.split_whitespace().filter_map(|v| v.parse().ok()).collect();
    // Fields after the command name start at field 3 (state, not a number, is skipped).
    f.get(10).zip(f.get(11)).map_or(f64::NAN, |(u, s)| (u + s) / 100.0)
}

/// Wall and CPU seconds of `f`.
fn timed<T>(f: impl FnOnce() -> T) -> (T, f64, f64) {
    let (t, c) = (Instant::now(), cpu_seconds());
    let out = f();
    (out, t.elapsed().as_secs_f64(), cpu_seconds() - c)
}

fn main() {
    let settings = preset(DEFAULT_PRESET).expect("default preset");
    let cams = settings.rig.build(&settings.lens, &settings.aabb, settings.seed).expect("rig");
    let phantom = Phantom::build(&settings.phantom, &settings.aabb, settings.seed, None).expect("phantom");
    let dims = settings.truth_dims(&settings.aabb);
    let voxels = dims.iter().product::<usize>();
    println!(
        "preset {DEFAULT_PRESET}: truth {dims:?}, {} cameras of {}×{} px, {} rayon threads; timing {CAMERAS} cameras",
        cams.len(),
        settings.lens.resolution[0],
        settings.lens.resolution[1],
        rayon::current_num_threads()
    );

    let (vol, s, cpu) = timed(|| Volume::from_field(dims, settings.aabb, &phantom, 0.0));
    println!(
        "jet voxelisation : {:>8.2} M voxels/s, {:>8.2} M voxels per CPU-s  ({voxels} voxels in {s:.2} s)",
        voxels as f64 / s / 1e6,
        voxels as f64 / cpu / 1e6
    );

    let pin = PinholeSettings::default();
    let (rays, s, cpu) = timed(|| {
        cams.iter()
            .take(CAMERAS)
            .map(|c| pinhole::render_volume_counting(&vol, &c.camera, &pin, 1.0).expect("pinhole").1)
            .sum::<u64>()
    });
    println!(
        "pinhole (voxels) : {:>8.2} M rays/s,    {:>8.2} M rays per CPU-s     ({rays} rays, {}×{} per pixel, step {} voxel, in {s:.2} s)",
        rays as f64 / s / 1e6,
        rays as f64 / cpu / 1e6,
        pin.supersample,
        pin.supersample,
        pin.step_fraction
    );

    let thin = match &settings.image {
        ImageModel::ThinLens(t) => t.clone(),
        ImageModel::Pinhole(_) => ThinLensSettings::default(),
    };
    let t = Instant::now();
    let emitters = Emitters::from_volume(&vol, thin.threshold);
    let s_em = t.elapsed().as_secs_f64();
    let (rays, s, cpu) = timed(|| {
        cams.iter()
            .take(CAMERAS)
            .enumerate()
            .map(|(i, c)| thin_lens::render(&emitters, &c.camera, &thin, 1.0, i as u64).expect("thin lens").1)
            .sum::<u64>()
    });
    println!(
        "thin lens        : {:>8.2} M rays/s,    {:>8.2} M rays per CPU-s     ({rays} rays from {} emitters, N_rays {}, in {s:.2} s; emitter list {s_em:.2} s)",
        rays as f64 / s / 1e6,
        rays as f64 / cpu / 1e6,
        emitters.len(),
        thin.rays_per_voxel
    );
    // The same images from the loop compiled for the baseline alone, which `render` replaces
    // with AVX2 or AVX-512 where the CPU has them.
    let (base, s_base, cpu_base) = timed(|| {
        cams.iter()
            .take(CAMERAS)
            .enumerate()
            .map(|(i, c)| thin_lens::render_baseline(&emitters, &c.camera, &thin, 1.0, i as u64).expect("thin lens").1)
            .sum::<u64>()
    });
    println!(
        "thin lens, baseline loop: {:>8.2} M rays/s, {:>8.2} M rays per CPU-s  (in {s_base:.2} s; the run-time choice x{:.2}, same rays: {})",
        base as f64 / s_base / 1e6,
        base as f64 / cpu_base / 1e6,
        s_base / s,
        base == rays
    );
}
