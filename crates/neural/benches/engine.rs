//! Training-engine benchmark: samples per second of one training step (forward + MSE +
//! backward + gradient reduction + Adam) for the dissertation's 8 × 256 ReLU network and for
//! the hash-grid field, the batch split over all threads in chunks as the trainer does, plus
//! the same 8 × 256 step in PyTorch-CPU (benches/pytorch_step.py) in the same run, and the
//! measured FP32 FMA peak of the machine.
//!
//! `--method-only` times whole training iterations through `train::train` instead (ray
//! batch, sampling, coarse pass, field, quadrature, loss, backward, Adam: the method driving
//! the CPU engine) on a ball seen by 8 cameras, for the faithful network and the `fast` grid.
//!
//! Build, then run the executable directly (the target dir is shared):
//!   cargo bench --no-run -p fluidnerf-neural --bench engine
//!   target/release/deps/engine-<hash> [--quick] [--no-pytorch] [--mlp-only | --grid-only | --method-only]
//! Environment: FLUIDNERF_BENCH_PYTHON (default python3).
#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::ops::ControlFlow;
use std::time::Instant;

use fluidnerf_core::{render_image, Aabb, Camera, Intrinsics, RenderSettings};
use fluidnerf_neural::optim::{sum_gradients, Adam, AdamConfig};
use fluidnerf_neural::train::{train, Learner, Prepared, Problem, StopRule, TrainConfig, View};
use fluidnerf_neural::trained::NeuralConfig;
use fluidnerf_neural::{HashGridConfig, HashGridField, MlpConfig, MlpField, MlpPrecision, TrainableField};
use glam::{DVec3, Vec3};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

/// One thread's tape, gradient buffer and scratch.
struct Worker<T> {
    tape: T,
    grads: Vec<f32>,
    out: Vec<f32>,
    d_out: Vec<f32>,
}

/// One training step over `batch` rows: every thread takes a contiguous share and runs it in
/// chunks of `chunk` rows (forward, MSE gradient, backward into its own buffer); then the
/// buffers are summed and Adam steps. Returns the loss.
fn train_step<F: TrainableField>(
    field: &mut F,
    workers: &mut [Worker<F::Tape>],
    inputs: &[f32],
    targets: &[f32],
    chunk: usize,
    grads: &mut [f32],
    adam: &mut Adam,
) -> f64 {
    let d = field.input_dim();
    let batch = targets.len();
    let per = batch.div_ceil(workers.len());
    let f: &F = field;
    let loss: f64 = workers
        .par_iter_mut()
        .enumerate()
        .map(|(t, w)| {
            let mut loss = 0.0f64;
            let end = ((t + 1) * per).min(batch);
            let mut i = t * per;
            while i < end {
                let n = chunk.min(end - i);
                let (out, d_out) = (&mut w.out[..n], &mut w.d_out[..n]);
                f.forward(&inputs[i * d..(i + n) * d], out, &mut w.tape);
                for ((g, &o), &y) in d_out.iter_mut().zip(out.iter()).zip(&targets[i..i + n]) {
                    let r = o - y;
                    loss += (r * r) as f64;
                    *g = 2.0 * r / batch as f32;
                }
                f.backward(&mut w.tape, d_out, &mut w.grads);
                i += n;
            }
            loss
        })
        .sum();
    let mut per_thread: Vec<Vec<f32>> = workers.iter_mut().map(|w| std::mem::take(&mut w.grads)).collect();
    sum_gradients(&mut per_thread, grads);
    for (w, g) in workers.iter_mut().zip(per_thread) {
        w.grads = g;
    }
    adam.step(field.params_mut(), grads, 5e-4);
    loss / batch as f64
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median seconds per step over `steps` timed steps after `warmup`.
fn time_steps<F: TrainableField>(field: &mut F, batch: usize, chunk: usize, warmup: usize, steps: usize) -> Timing {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let inputs: Vec<f32> = (0..batch * field.input_dim()).map(|_| rng.random::<f32>()).collect();
    time_steps_on(field, &inputs, chunk, warmup, steps)
}

/// `batch` 3D points along random chords of the unit box, `per_ray` consecutive samples per
/// chord (stratified), the order in which the trainer evaluates them.
fn ray_points(batch: usize, per_ray: usize) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let mut pts = Vec::with_capacity(batch * 3);
    while pts.len() < batch * 3 {
        let a: [f32; 3] = std::array::from_fn(|_| rng.random());
        let b: [f32; 3] = std::array::from_fn(|_| rng.random());
        for j in 0..per_ray {
            let s = (j as f32 + rng.random::<f32>()) / per_ray as f32;
            pts.extend((0..3).map(|k| a[k] + s * (b[k] - a[k])));
        }
    }
    pts.truncate(batch * 3);
    pts
}

fn time_steps_on<F: TrainableField>(
    field: &mut F,
    inputs: &[f32],
    chunk: usize,
    warmup: usize,
    steps: usize,
) -> Timing {
    let threads = rayon::current_num_threads();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let batch = inputs.len() / field.input_dim();
    let targets: Vec<f32> = (0..batch).map(|_| rng.random::<f32>()).collect();
    let mut workers: Vec<Worker<F::Tape>> = (0..threads)
        .map(|_| Worker {
            tape: field.new_tape(),
            grads: vec![0.0; field.num_params()],
            out: vec![0.0; chunk],
            d_out: vec![0.0; chunk],
        })
        .collect();
    let mut grads = vec![0.0; field.num_params()];
    let mut adam = Adam::new(field.num_params(), AdamConfig::default());
    let mut times = Vec::new();
    let mut cpu = Vec::new();
    for s in 0..warmup + steps {
        let (t0, c0) = (Instant::now(), process_cpu_s());
        let loss = train_step(field, &mut workers, inputs, &targets, chunk, &mut grads, &mut adam);
        let (dt, dc) = (t0.elapsed().as_secs_f64(), process_cpu_s() - c0);
        assert!(loss.is_finite(), "training step diverged");
        if s >= warmup {
            times.push(dt);
            cpu.push(dc / threads as f64);
        }
    }
    Timing { wall_s: median(times), cpu_s: median(cpu) }
}

/// Median time of `eval` over `batch` random rows, split over the threads in chunks.
fn time_eval<F: TrainableField>(field: &F, batch: usize, chunk: usize, steps: usize) -> Timing {
    let threads = rayon::current_num_threads();
    let d = field.input_dim();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let inputs: Vec<f32> = (0..batch * d).map(|_| rng.random::<f32>()).collect();
    let mut out = vec![0.0f32; batch];
    let mut tapes: Vec<F::Tape> = (0..threads).map(|_| field.new_tape()).collect();
    let per = batch.div_ceil(threads);
    let (mut times, mut cpu) = (Vec::new(), Vec::new());
    for s in 0..steps + 1 {
        let (t0, c0) = (Instant::now(), process_cpu_s());
        tapes.par_iter_mut().zip(out.par_chunks_mut(per)).enumerate().for_each(|(t, (tape, out))| {
            for (k, o) in out.chunks_mut(chunk).enumerate() {
                let i = t * per + k * chunk;
                field.eval(&inputs[i * d..(i + o.len()) * d], o, tape);
            }
        });
        let (dt, dc) = (t0.elapsed().as_secs_f64(), process_cpu_s() - c0);
        if s > 0 {
            times.push(dt);
            cpu.push(dc / threads as f64);
        }
    }
    Timing { wall_s: median(times), cpu_s: median(cpu) }
}

/// Seconds per step: wall clock, and process CPU time divided by the number of threads
/// ("core-normalised": what the wall time would be if every thread had a core to itself —
/// the honest figure on a machine shared with other jobs; spinning idle threads make it
/// conservative).
#[derive(Clone, Copy, Debug)]
struct Timing {
    wall_s: f64,
    cpu_s: f64,
}

/// CPU time (user + system) of this process so far, from /proc/self/stat (clock ticks of
/// 1/100 s); NaN where unavailable.
fn process_cpu_s() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return f64::NAN };
    let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else { return f64::NAN };
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| f.get(i).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (ticks(11) + ticks(12)) / 100.0
}

/// Measured FP32 peak (GFLOP/s) of all threads, (wall, core-normalised): independent chains
/// of 512-bit (or 256-bit) FMAs, enough of them to cover the FMA latency.
fn fma_peak_gflops() -> (f64, f64) {
    #[cfg(target_arch = "x86_64")]
    {
        // AVX-512 intrinsics are stable since Rust 1.89 (the library's MSRV is 1.85; this
        // benchmark-only peak probe needs the newer toolchain).
        #[allow(clippy::incompatible_msrv)]
        #[target_feature(enable = "avx512f")]
        fn chains512(iters: usize) -> f32 {
            use std::arch::x86_64::*;
            let mut acc = [_mm512_set1_ps(0.0); 12];
            let a = _mm512_set1_ps(0.999_999);
            let b = _mm512_set1_ps(1e-7);
            for _ in 0..iters {
                for v in acc.iter_mut() {
                    *v = _mm512_fmadd_ps(*v, a, b);
                }
            }
            let mut s = 0.0;
            for v in acc {
                s += _mm512_reduce_add_ps(v);
            }
            s
        }
        #[target_feature(enable = "avx2,fma")]
        fn chains256(iters: usize) -> f32 {
            use std::arch::x86_64::*;
            let mut acc = [_mm256_set1_ps(0.0); 12];
            let a = _mm256_set1_ps(0.999_999);
            let b = _mm256_set1_ps(1e-7);
            for _ in 0..iters {
                for v in acc.iter_mut() {
                    *v = _mm256_fmadd_ps(*v, a, b);
                }
            }
            let mut s = [0.0f32; 8];
            for v in acc {
                let mut t = [0.0f32; 8];
                // SAFETY: `t` holds 8 f32.
                unsafe { _mm256_storeu_ps(t.as_mut_ptr(), v) };
                for (s, t) in s.iter_mut().zip(t) {
                    *s += t;
                }
            }
            s.iter().sum()
        }
        let (lanes, run): (usize, fn(usize) -> f32) = if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: feature detected above.
            (16, |n| unsafe { chains512(n) })
        } else if std::arch::is_x86_feature_detected!("fma") {
            // SAFETY: feature detected above.
            (8, |n| unsafe { chains256(n) })
        } else {
            return (f64::NAN, f64::NAN);
        };
        let iters = 20_000_000usize;
        let threads = rayon::current_num_threads();
        let mut best = (0.0f64, 0.0f64);
        for _ in 0..3 {
            let (t0, c0) = (Instant::now(), process_cpu_s());
            let s: f32 = (0..threads).into_par_iter().map(|_| run(iters)).sum();
            let (dt, dc) = (t0.elapsed().as_secs_f64(), (process_cpu_s() - c0) / threads as f64);
            assert!(s.is_finite());
            let flop = (threads * iters * 12 * lanes * 2) as f64 / 1e9;
            best = (best.0.max(flop / dt), best.1.max(flop / dc));
        }
        best
    }
    #[cfg(not(target_arch = "x86_64"))]
    (f64::NAN, f64::NAN)
}

/// PyTorch's samples/s: (wall, core-normalised).
fn pytorch(batch: usize, steps: usize, threads: usize) -> Option<(f64, f64)> {
    let python = std::env::var("FLUIDNERF_BENCH_PYTHON").unwrap_or_else(|_| "python3".into());
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/pytorch_step.py");
    let out = std::process::Command::new(python)
        .args([script, "--batch", &batch.to_string(), "--steps", &steps.to_string()])
        .args(["--threads", &threads.to_string()])
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        eprintln!("pytorch reference failed: {}", String::from_utf8_lossy(&out.stderr).trim());
        return None;
    }
    println!("  {}", text.trim());
    let field =
        |key: &str| text.split_whitespace().find_map(|w| w.strip_prefix(key)).and_then(|v| v.parse::<f64>().ok());
    Some((field("samples_per_s=")?, field("samples_per_cpu_s=")?))
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.iter().any(|a| a == "--peak-only") {
        let (w, c) = fma_peak_gflops();
        println!("FP32 FMA peak: {w:.0} | {c:.0} GFLOP/s");
        return;
    }
    let quick = args.iter().any(|a| a == "--quick");
    let no_torch = args.iter().any(|a| a == "--no-pytorch");
    let grid_only = args.iter().any(|a| a == "--grid-only");
    let mlp_only = args.iter().any(|a| a == "--mlp-only");
    let threads = rayon::current_num_threads();
    let steps = if quick { 3 } else { 8 };
    println!("training-engine benchmark: {threads} threads, median of {steps} steps");
    println!("rates: wall clock | core-normalised (process CPU time / threads)");
    if args.iter().any(|a| a == "--method-only") {
        method_benches(steps);
        return;
    }
    if !grid_only {
        mlp_benches(65_536, steps, threads, no_torch);
    }
    if !mlp_only {
        grid_benches(steps);
        space_time_benches(steps);
    }
}

fn mlp_benches(batch: usize, steps: usize, threads: usize, no_torch: bool) {
    let (peak, peak_cpu) = fma_peak_gflops();
    println!("FP32 FMA peak (measured, {threads} threads): {peak:.0} | {peak_cpu:.0} GFLOP/s");
    let mut mlp = MlpField::new(&MlpConfig::table_5_1(), 3, 0).expect("default config is valid");
    let flops = mlp.flops_per_sample();
    println!("mlp 8x256 relu: batch {batch}, {:.2} MFLOP per sample (forward + backward)", flops / 1e6);
    let mut rust = Vec::new();
    for chunk in [128, 256, 512, 8192] {
        let t = time_steps(&mut mlp, batch, chunk, 1, steps);
        let (rw, rc) = (batch as f64 / t.wall_s, batch as f64 / t.cpu_s);
        println!(
            "mlp 8x256 relu  chunk {chunk:4}: {rw:8.0} | {rc:8.0} samples/s   {:5.0} | {:5.0} GFLOP/s",
            rw * flops / 1e9,
            rc * flops / 1e9,
        );
        if chunk == 256 {
            rust.push((rw, rc));
        }
    }
    let torch = if no_torch { None } else { pytorch(batch, steps.min(5), threads) };
    // Rust again after PyTorch, so both see the same machine state.
    let t = time_steps(&mut mlp, batch, 256, 1, steps);
    rust.push((batch as f64 / t.wall_s, batch as f64 / t.cpu_s));
    let rw = rust.iter().map(|r| r.0).sum::<f64>() / rust.len() as f64;
    let rc = rust.iter().map(|r| r.1).sum::<f64>() / rust.len() as f64;
    println!("mlp 8x256 relu  chunk  256, mean of before/after pytorch: {rw:.0} | {rc:.0} samples/s");
    println!(
        "  = {:.0} | {:.0} GFLOP/s = {:.0} | {:.0} % of the measured FMA peak",
        rw * flops / 1e9,
        rc * flops / 1e9,
        100.0 * rw * flops / 1e9 / peak,
        100.0 * rc * flops / 1e9 / peak_cpu
    );
    if let Some((pw, pc)) = torch {
        println!("ratio rust / pytorch: {:.2}x wall | {:.2}x core-normalised", rw / pw, rc / pc);
    }

    for chunk in [256, 8192] {
        let t = time_eval(&mlp, batch, chunk, steps);
        println!(
            "mlp 8x256 relu  inference (eval) chunk {chunk:5}: {:8.0} | {:8.0} samples/s",
            batch as f64 / t.wall_s,
            batch as f64 / t.cpu_s
        );
    }

    let mut swish = MlpField::new(&MlpConfig::table_5_2(), 4, 0).expect("Table 5.2 config is valid");
    let t = time_steps(&mut swish, batch, 256, 1, steps);
    println!(
        "mlp 10x200 swish (4D, Table 5.2) chunk 256: {:8.0} | {:8.0} samples/s",
        batch as f64 / t.wall_s,
        batch as f64 / t.cpu_s
    );
}

fn grid_benches(steps: usize) {
    let grid_batch = 1 << 18;
    let log2: u32 = std::env::var("GRID_LOG2").ok().and_then(|v| v.parse().ok()).unwrap_or(19);
    let along_rays = ray_points(grid_batch, 128);
    let configs = [
        ("instant-ngp defaults", HashGridConfig { log2_table_size: log2, ..HashGridConfig::default() }),
        (
            "small: 8 levels, max res 128, 2^16",
            HashGridConfig { levels: 8, log2_table_size: 16, max_resolution: 128, ..HashGridConfig::default() },
        ),
    ];
    for (name, cfg) in configs {
        let mut grid = HashGridField::new(&cfg, 3, 0).expect("benchmark config is valid");
        println!(
            "hash grid ({name}): {} levels x {} features, 2^{} entries, max res {}, MLP {}x{}, {} params ({} in tables), batch {grid_batch}",
            cfg.levels,
            cfg.features_per_level,
            cfg.log2_table_size,
            cfg.max_resolution,
            cfg.mlp_depth,
            cfg.mlp_width,
            grid.num_params(),
            grid.grid_params()
        );
        // The encoding's forward pass scalar and vectorised (where the CPU has AVX2 and FMA).
        for chunk in [4096, 32_768] {
            for vectorised in [false, true] {
                fluidnerf_neural::hashgrid::set_vectorised(vectorised);
                let encode = if vectorised { "vector" } else { "scalar" };
                for (what, t) in [
                    ("random points", time_steps(&mut grid, grid_batch, chunk, 1, steps)),
                    ("along rays   ", time_steps_on(&mut grid, &along_rays, chunk, 1, steps)),
                ] {
                    println!(
                        "  chunk {chunk:6} {encode} encoding, {what}: {:5.2} | {:5.2} M points/s",
                        grid_batch as f64 / t.wall_s / 1e6,
                        grid_batch as f64 / t.cpu_s / 1e6
                    );
                }
            }
        }
    }
}

/// The space–time grid of a three-frame `tr-fast` window: a step over points along rays at one
/// frame's time (as every training chunk is: the corners of the other time vertex are
/// skipped) and at a time between frames (all 16 corners).
fn space_time_benches(steps: usize) {
    let batch = 1 << 18;
    let preset = fluidnerf_neural::temporal::temporal_preset("tr-fast").expect("tr-fast exists");
    let fluidnerf_neural::trained::FieldConfig::HashGrid(cfg) =
        fluidnerf_neural::temporal::field_for_window(&preset.field, 3)
    else {
        unreachable!("tr-fast is a hash grid")
    };
    let mut grid = HashGridField::new(&cfg, 4, 0).expect("benchmark config is valid");
    println!(
        "space-time grid (tr-fast, 3 frames): {} levels x {} features, 2^{} entries, {} params, batch {batch}",
        cfg.levels,
        cfg.features_per_level,
        cfg.log2_table_size,
        grid.num_params()
    );
    let along = ray_points(batch, 128);
    for (what, t) in [("at a frame's time  ", 1.0f32), ("between two frames ", 1.5)] {
        let inputs: Vec<f32> = along.chunks(3).flat_map(|p| [p[0], p[1], p[2], t]).collect();
        let timing = time_steps_on(&mut grid, &inputs, 8192, 1, steps);
        println!(
            "  chunk   8192 points along rays {what}: {:5.2} | {:5.2} M points/s",
            batch as f64 / timing.wall_s / 1e6,
            batch as f64 / timing.cpu_s / 1e6
        );
    }
}

/// 8 cameras on a half ring, 64² pixels each, looking at a ball of radius 0.6 (smooth edge) in
/// a box of side 2: the images the method benchmarks train on.
fn ball_problem() -> Problem {
    let aabb = Aabb::cube(DVec3::ZERO, 2.0);
    let ball = |p: Vec3, _t: f64| {
        let r = (p.as_dvec3() - DVec3::new(0.1, -0.1, 0.05)).length();
        (0.5 + 0.5 * (std::f64::consts::PI * ((r - 0.4) / 0.4).clamp(0.0, 1.0)).cos()) as f32
    };
    let px = 64u32;
    let k = Intrinsics {
        width: px,
        height: px,
        fx: px as f64 * 1.9,
        fy: px as f64 * 1.9,
        cx: (px as f64 - 1.0) / 2.0,
        cy: (px as f64 - 1.0) / 2.0,
        skew: 0.0,
    };
    let settings = RenderSettings { scale: 3.0, ..Default::default() };
    let views = (0..8)
        .map(|c| {
            let a = std::f64::consts::PI * c as f64 / 8.0;
            let camera = Camera::look_at(k, DVec3::new(0.0, 5.0 * a.cos(), 5.0 * a.sin()), DVec3::ZERO, DVec3::X);
            let image = render_image(&ball, &camera, &aabb, &settings).expect("renders");
            View { camera, image, time: 0.0 }
        })
        .collect();
    Problem { aabb, intensity_scale: 3.0, views, holdout: Vec::new(), time_step: 1.0 }
}

/// Seconds per iteration of `train` over `iterations` iterations after one warm-up iteration:
/// the median wall time and the mean core-normalised CPU time (the CPU clock ticks at 10 ms, too
/// coarse for a median of short iterations); returns the timing and the field rows per iteration.
fn time_iterations<F: TrainableField>(
    prep: &Prepared,
    field: F,
    cfg: &TrainConfig,
    iterations: usize,
) -> (Timing, usize) {
    let threads = rayon::current_num_threads();
    let cfg = TrainConfig {
        max_iterations: iterations + 1,
        validate_every: 0,
        stop: StopRule { window: 0, ..StopRule::default() },
        ..cfg.clone()
    };
    let mut learner = Learner::fresh(field, prep, &cfg);
    let (mut times, mut cpu, mut rows) = (Vec::new(), Vec::new(), 0);
    let mut last = (Instant::now(), process_cpu_s());
    train(prep, &mut learner, &cfg, 0, |s| {
        let now = (Instant::now(), process_cpu_s());
        if s.iteration > 1 {
            times.push((now.0 - last.0).as_secs_f64());
            cpu.push((now.1 - last.1) / threads as f64);
        }
        rows = s.samples;
        last = now;
        ControlFlow::Continue(())
    })
    .expect("trains");
    let cpu_s = cpu.iter().sum::<f64>() / cpu.len() as f64;
    (Timing { wall_s: median(times), cpu_s }, rows)
}

fn method_benches(steps: usize) {
    let problem = ball_problem();
    let faithful = NeuralConfig::preset("ch7").expect("preset").train;
    let faithful = TrainConfig { rays_per_image: 64, ..faithful };
    let prep = Prepared::new(&problem, &faithful).expect("prepares");
    let mlp = MlpField::new(&MlpConfig::table_5_1(), 3, 0).expect("default config is valid");
    let (t, rows) = time_iterations(&prep, mlp, &faithful, steps);
    println!(
        "method, 8 x 256 relu (ch7: 64 + 64 samples, 8 x 64 rays, chunk 256): {:.3} | {:.3} s/iteration, {:.0} | {:.0} rows/s",
        t.wall_s,
        t.cpu_s,
        rows as f64 / t.wall_s,
        rows as f64 / t.cpu_s
    );
    // The preset, then its decoder's products in f32, then also the chunk it had before
    // (8192 samples): each line's ratio is to the last one's time, all from this run.
    let fast = NeuralConfig::preset("fast").expect("preset");
    let fluidnerf_neural::trained::FieldConfig::HashGrid(grid) = fast.field else { unreachable!("fast is a grid") };
    let f32_grid = HashGridConfig { mlp_precision: MlpPrecision::F32, ..grid.clone() };
    let preset_train = TrainConfig { rays_per_image: 2048, ..fast.train };
    let old_chunk = TrainConfig { chunk_samples: 8192, ..preset_train.clone() };
    let variants = [
        ("the preset", &grid, &preset_train),
        ("f32 products", &f32_grid, &preset_train),
        ("f32, chunk 8192", &f32_grid, &old_chunk),
    ];
    let timings: Vec<(Timing, usize, &str, usize)> = variants
        .iter()
        .map(|&(_, grid, cfg)| {
            let prep = Prepared::new(&problem, cfg).expect("prepares");
            let field = HashGridField::new(grid, 3, 0).expect("preset is valid");
            let products = if field.bf16_products() { "bf16" } else { "f32" };
            let (t, rows) = time_iterations(&prep, field, cfg, 4 * steps);
            (t, rows, products, cfg.chunk_samples)
        })
        .collect();
    let reference = timings.last().expect("three variants").0.cpu_s;
    for ((name, ..), (t, rows, products, chunk)) in variants.iter().zip(&timings) {
        println!(
            "method, fast grid, {name} (48 samples, skipping, 8 x 2048 rays, chunk {chunk}, {products} products): {:.4} | {:.4} s/iteration, {:.2} | {:.2} M rows/s, x{:.2} against f32 and chunk 8192 (core-normalised)",
            t.wall_s,
            t.cpu_s,
            *rows as f64 / t.wall_s / 1e6,
            *rows as f64 / t.cpu_s / 1e6,
            reference / t.cpu_s
        );
    }
}
