//! Time-resolved training end to end on a Gaussian blob moving along the ring axis, seen by 6
//! cameras at 24² pixels: one-time-step batching, TR-FluidNeRF against a bound, a held-out time
//! between two training frames against linear interpolation, and sliding windows (warm start,
//! continuity of the stitched field, round trip through a run directory).

use std::ops::ControlFlow;

use fluidnerf_core::{render_image, Aabb, RenderSettings, ScalarField, Volume};
use fluidnerf_neural::hashgrid::{HashGridConfig, HashGridField};
use fluidnerf_neural::mlp::{Activation, MlpConfig, MlpField};
use fluidnerf_neural::temporal::{
    field_for_window, frame_times, load_temporal, train_windows, FrameStart, ResumeState, StitchedField,
    TemporalRecord, TemporalRun, TimeAxis, TimeOrigin, WindowConfig, WindowEvent, WindowRecord,
};
use fluidnerf_neural::train::{Batching, Learner, Problem, StopRule, TrainConfig, View, ViewMasks};
use fluidnerf_neural::trained::FieldConfig;
use fluidnerf_neural::weights::{checkpoint_bytes, load_checkpoint};
use fluidnerf_neural::TrainableField;
use glam::{DVec3, Vec3};

use crate::common;
use common::ring;

const SIGMA: f64 = 0.2;

/// Centre of the blob at time t: it moves 0.225 length units (≈ 1.1 σ) per time unit along +x.
fn centre(t: f64) -> DVec3 {
    DVec3::new(-0.45 + 0.225 * t, 0.05, -0.05)
}

fn blob(p: DVec3, t: f64) -> f32 {
    (-(p - centre(t)).length_squared() / (2.0 * SIGMA * SIGMA)).exp() as f32
}

fn aabb() -> Aabb {
    Aabb::cube(DVec3::ZERO, 2.0)
}

/// 6 cameras × the given times.
fn problem(times: &[f64]) -> Problem {
    let settings = RenderSettings { supersample: 2, scale: 3.0, ..Default::default() };
    let mut views = Vec::new();
    for &t in times {
        let field = move |p: Vec3, _: f64| blob(p.as_dvec3(), t);
        for camera in ring(6, 24) {
            let image = render_image(&field, &camera, &aabb(), &settings).expect("renders");
            views.push(View { camera, image, time: t });
        }
    }
    Problem { aabb: aabb(), intensity_scale: 3.0, views, holdout: Vec::new(), time_step: 1.0 }
}

fn truth(t: f64) -> Volume {
    Volume::from_fn([24, 24, 24], aabb(), |p| blob(p, t))
}

fn nrmse(a: &[f32], truth: &[f32]) -> f64 {
    let num: f64 = a.iter().zip(truth).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
    let den: f64 = truth.iter().map(|y| (*y as f64).powi(2)).sum();
    (num / den).sqrt()
}

fn quick(iterations: usize, lr: f32) -> TrainConfig {
    let mut cfg = TrainConfig {
        rays_per_image: 64,
        coarse_samples: 16,
        fine_samples: 16,
        max_iterations: iterations,
        validate_every: 0,
        stop: StopRule { window: 0, ..Default::default() },
        batching: Batching::OneTimeStep,
        ..Default::default()
    };
    cfg.schedule.initial = lr;
    cfg.schedule.at_decay_iters = lr / 10.0;
    cfg.schedule.decay_iters = iterations as u64;
    cfg
}

fn small_tr_mlp() -> MlpConfig {
    MlpConfig {
        depth: 4,
        width: 64,
        space_freqs: 4,
        time_freqs: 1,
        activation: Activation::Swish,
        ..MlpConfig::default()
    }
}

#[test]
fn one_time_step_batching_draws_from_one_frame_per_iteration() {
    let p = problem(&[0.0, 1.0, 2.0]);
    let field = MlpField::new(&small_tr_mlp(), 4, 1).expect("field");
    let count = |batching: Batching| {
        let cfg = TrainConfig { batching, ..quick(3, 1e-3) };
        let prep = fluidnerf_neural::train::Prepared::new(&p, &cfg).expect("prepares");
        let mut learner = fluidnerf_neural::train::Learner::new(field.clone());
        let mut samples = Vec::new();
        fluidnerf_neural::train::train(&prep, &mut learner, &cfg, 0, |s| {
            samples.push(s.samples);
            ControlFlow::Continue(())
        })
        .expect("trains");
        samples
    };
    let all = count(Batching::AllViews);
    let one = count(Batching::OneTimeStep);
    // Every training ray sees the box here, so a frame is exactly a third of the rays.
    for (a, o) in all.iter().zip(&one) {
        assert_eq!(*a, 3 * o, "one time step must take a third of the samples: {all:?} vs {one:?}");
    }
}

#[test]
fn tr_fluidnerf_reconstructs_frames_and_a_held_out_time() {
    // Frames at t = 0, 2, 4 (Δt = 2) are trained; t = 1 and 3 lie halfway between and are never
    // seen. Linear interpolation of the two neighbouring frames (here of their exact truths,
    // the best any per-frame reconstruction could do) blurs the blob into two half-blobs.
    // L_t = 0 (Table 5.2): with t' = t/Δt integer at every frame, sin(2^k π t') vanishes and
    // cos(2^k π t') is ±1 there, so L_t ≥ 1 features are never seen between frames.
    let p = problem(&[0.0, 2.0, 4.0]);
    let p = Problem { time_step: 2.0, ..p };
    let cfg = quick(600, 5e-3);
    let init = MlpField::new(&MlpConfig { time_freqs: 0, ..small_tr_mlp() }, 4, 7).expect("field");
    let run = train_windows(
        &p,
        &ViewMasks::default(),
        &cfg,
        &WindowConfig::default(),
        init,
        3,
        ResumeState::default(),
        None,
        |_| ControlFlow::Continue(()),
    )
    .expect("trains");
    assert_eq!(run.windows.len(), 1);
    let field = StitchedField::from_run(&run).expect("stitches");
    let at = |t: f64| Volume::from_field([24, 24, 24], aabb(), &field, t);
    let mut frame_errors = Vec::new();
    for t in [0.0, 2.0, 4.0] {
        frame_errors.push(nrmse(&at(t).data, &truth(t).data));
    }
    assert!(frame_errors.iter().all(|&e| e < 0.3), "trained frames NRMSE {frame_errors:?}");
    for (t, (a, b)) in [(1.0, (0.0, 2.0)), (3.0, (2.0, 4.0))] {
        let tr = nrmse(&at(t).data, &truth(t).data);
        let (ta, tb) = (truth(a), truth(b));
        let lerp: Vec<f32> = ta.data.iter().zip(&tb.data).map(|(x, y)| 0.5 * (x + y)).collect();
        let linear = nrmse(&lerp, &truth(t).data);
        assert!(tr < linear, "held-out t = {t}: TR NRMSE {tr:.3} vs linear interpolation of the truths {linear:.3}");
    }
}

fn small_grid() -> HashGridConfig {
    HashGridConfig {
        levels: 4,
        features_per_level: 2,
        log2_table_size: 12,
        base_resolution: 4,
        max_resolution: 24,
        mlp_depth: 1,
        mlp_width: 16,
        ..HashGridConfig::default()
    }
}

/// The small space–time grid for windows of `frames` frames (its configuration and a fresh
/// field), and the training settings the window tests share.
fn grid_windows_setup(frames: usize) -> (FieldConfig, HashGridField, TrainConfig) {
    let field_cfg = field_for_window(&FieldConfig::HashGrid(small_grid()), frames);
    let FieldConfig::HashGrid(grid) = &field_cfg else { unreachable!() };
    let init = HashGridField::new(grid, 4, 2).expect("field");
    let cfg = TrainConfig {
        occupancy: Some(fluidnerf_neural::occupancy::OccupancyConfig::default()),
        rays_per_image: 128,
        coarse_samples: 32,
        fine_samples: 0,
        ..quick(300, 1e-2)
    };
    (field_cfg, init, cfg)
}

#[test]
fn windows_warm_start_stitch_continuously_and_round_trip() {
    let times = [0.0, 1.0, 2.0, 3.0];
    let p = problem(&times);
    let windows = WindowConfig { frames: 3, overlap: 2, time_origin: TimeOrigin::Window, ..WindowConfig::default() };
    let (field_cfg, init, cfg) = grid_windows_setup(3);
    let warm =
        train_windows(&p, &ViewMasks::default(), &cfg, &windows, init.clone(), 5, ResumeState::default(), None, |_| {
            ControlFlow::Continue(())
        })
        .expect("trains");
    assert_eq!(warm.plan, vec![0..3, 1..4]);
    let cold_cfg = WindowConfig { warm_start: false, ..windows.clone() };
    let cold = train_windows(&p, &ViewMasks::default(), &cfg, &cold_cfg, init, 5, ResumeState::default(), None, |_| {
        ControlFlow::Continue(())
    })
    .expect("trains");
    // The second window starts from a field that already knows its first frame.
    let first = |r: &TemporalRun<HashGridField>| r.windows[1].learner.losses[0];
    // (Both start from the mean level; the warm one also knows where the blob is.)
    assert!(first(&warm) < 0.7 * first(&cold), "warm start {} vs cold {}", first(&warm), first(&cold));

    // Every frame is reconstructed, and the stitched field is continuous across the overlap.
    let field = StitchedField::from_run(&warm).expect("stitches");
    let errors: Vec<f64> = times
        .iter()
        .map(|&t| nrmse(&Volume::from_field([24, 24, 24], aabb(), &field, t).data, &truth(t).data))
        .collect();
    let losses: Vec<f32> = warm.windows.iter().map(|w| w.report.smoothed_loss).collect();
    assert!(errors.iter().all(|&e| e < 0.35), "frame NRMSE {errors:?}, losses {losses:?}");
    let pts: Vec<Vec3> = (0..200).map(|i| Vec3::new(-0.8 + 0.008 * i as f32, 0.05, -0.05)).collect();
    let eval = |t: f64| {
        let mut out = vec![0.0f32; pts.len()];
        field.eval(&pts, t, &mut out);
        out
    };
    let scale = eval(2.0).iter().fold(0.0f32, |m, &v| m.max(v));
    let mut t = 0.5;
    while t < 2.5 {
        let (a, b) = (eval(t), eval(t + 0.01));
        let jump = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(jump < 0.05 * scale, "the stitched field jumps by {jump} (scale {scale}) at t = {t}");
        t += 0.01;
    }

    // A run directory rebuilds the same stitched field.
    let dir = tempfile::tempdir().expect("tempdir");
    let mut records = Vec::new();
    for (k, w) in warm.windows.iter().enumerate() {
        let name = format!("w{k}.safetensors");
        std::fs::write(
            dir.path().join(&name),
            fluidnerf_neural::weights::weights_bytes(&w.learner.field).expect("bytes"),
        )
        .expect("writes");
        records.push(WindowRecord {
            frames: [w.frames.start, w.frames.end],
            time_origin: w.time_origin,
            time_axis: w.time_axis,
            meta: w.meta.clone(),
            weights: name,
        });
    }
    let record =
        TemporalRecord { field: field_cfg.clone(), input_dim: 4, frame_times: frame_times(&p), windows: records };
    std::fs::write(dir.path().join("temporal.json"), serde_json::to_string(&record).expect("json")).expect("writes");
    let loaded = load_temporal(dir.path()).expect("loads");
    for t in [0.0, 1.7, 2.0, 3.3] {
        let mut a = vec![0.0f32; pts.len()];
        loaded.eval(&pts, t, &mut a);
        let mut b = vec![0.0f32; pts.len()];
        field.eval(&pts, t, &mut b);
        assert_eq!(a, b, "loaded field differs at t = {t}");
    }
}

/// Frames that are not evenly spaced (times 0, 1, 3): the space–time grid has one time vertex
/// per frame, so a time between the last two frames lies between their reconstructions (with
/// `t / Δt` the grid put time 2 onto the last frame's vertex, clamping every time past it).
#[test]
fn grid_windows_place_unevenly_spaced_frames_on_their_own_vertices() {
    let times = [0.0, 1.0, 3.0];
    let p = problem(&times);
    let windows = WindowConfig { frames: 3, overlap: 0, ..WindowConfig::default() };
    let (_, init, cfg) = grid_windows_setup(3);
    let run = train_windows(&p, &ViewMasks::default(), &cfg, &windows, init, 5, ResumeState::default(), None, |_| {
        ControlFlow::Continue(())
    })
    .expect("trains");
    assert_eq!(run.windows[0].time_axis, TimeAxis::Frames);
    let field = StitchedField::from_run(&run).expect("stitches");
    let at = |t: f64| Volume::from_field([24, 24, 24], aabb(), &field, t).data;
    for t in times {
        let e = nrmse(&at(t), &truth(t).data);
        assert!(e < 0.35, "frame at t = {t}: NRMSE {e:.3}");
    }
    // Where the field at t = 2 lies on the way from frame 1 to frame 3 (0 at 1, 1 at 3).
    let (a, b, m) = (at(1.0), at(3.0), at(2.0));
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for ((&a, &b), &m) in a.iter().zip(&b).zip(&m) {
        num += ((m - a) as f64) * ((b - a) as f64);
        den += ((b - a) as f64).powi(2);
    }
    let fraction = num / den;
    assert!((0.25..0.75).contains(&fraction), "t = 2 is {fraction:.2} of the way from frame 1 to frame 3");
}

#[test]
fn per_frame_windows_interpolate_linearly_between_frames() {
    // W = 1 with a 3D field is static per-frame FluidNeRF; between frames the stitched field
    // is the linear interpolation of the neighbouring reconstructions.
    let p = problem(&[0.0, 1.0]);
    let cfg = TrainConfig { batching: Batching::AllViews, ..quick(30, 5e-3) };
    let init = MlpField::new(&MlpConfig { time_freqs: 0, ..small_tr_mlp() }, 3, 1).expect("field");
    let run = train_windows(
        &p,
        &ViewMasks::default(),
        &cfg,
        &WindowConfig::per_frame(),
        init,
        0,
        ResumeState::default(),
        None,
        |_| ControlFlow::Continue(()),
    )
    .expect("trains");
    assert_eq!(run.windows.len(), 2);
    let field = StitchedField::from_run(&run).expect("stitches");
    let pts: Vec<Vec3> = (0..50).map(|i| Vec3::new(-0.5 + 0.02 * i as f32, 0.0, 0.0)).collect();
    let eval = |t: f64| {
        let mut out = vec![0.0f32; pts.len()];
        field.eval(&pts, t, &mut out);
        out
    };
    let (a, b, m) = (eval(0.0), eval(1.0), eval(0.25));
    for i in 0..pts.len() {
        let expect = 0.75 * a[i] + 0.25 * b[i];
        assert!((m[i] - expect).abs() <= 1e-5 * (1.0 + expect.abs()), "point {i}: {} vs {expect}", m[i]);
    }
}

/// Four frames in windows of 3 overlapping by 2 (0..3, 1..4), the small TR MLP, warm starts.
fn windowed_mlp(origin: TimeOrigin) -> (Problem, TrainConfig, WindowConfig, MlpField) {
    let p = problem(&[0.0, 1.0, 2.0, 3.0]);
    let windows = WindowConfig { frames: 3, overlap: 2, time_origin: origin, ..WindowConfig::default() };
    let init = MlpField::new(&MlpConfig { time_freqs: 0, ..small_tr_mlp() }, 4, 4).expect("field");
    (p, quick(90, 5e-3), windows, init)
}

/// A learner through the checkpoint format and back (what a resumed run reads).
fn through_checkpoint(learner: &Learner<MlpField>, init: &MlpField) -> Learner<MlpField> {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("w.checkpoint.safetensors");
    std::fs::write(&path, checkpoint_bytes(learner).expect("bytes")).expect("writes");
    let mut back = Learner::new(init.clone());
    load_checkpoint(&path, &mut back).expect("loads");
    back
}

#[test]
fn an_interrupted_windowed_run_resumes_to_the_uninterrupted_result() {
    let (p, cfg, windows, init) = windowed_mlp(TimeOrigin::Recording);
    let cfg = TrainConfig { max_iterations: 40, ..cfg };
    let go = |_: WindowEvent<'_, MlpField>| ControlFlow::Continue(());
    let full =
        train_windows(&p, &ViewMasks::default(), &cfg, &windows, init.clone(), 9, ResumeState::default(), None, go)
            .expect("trains");
    assert_eq!(full.plan, vec![0..3, 1..4]);
    assert!(!full.interrupted);

    // Stopped inside the second window (after its 17th iteration), or right after the first.
    let inside = |e: WindowEvent<'_, MlpField>| match e {
        WindowEvent::Iteration(w, s) if w.index == 1 && s.iteration == 17 => ControlFlow::Break(()),
        _ => ControlFlow::Continue(()),
    };
    let between = |e: WindowEvent<'_, MlpField>| match e {
        WindowEvent::Finished(w, _) if w.index == 0 => ControlFlow::Break(()),
        _ => ControlFlow::Continue(()),
    };
    let stopped_inside =
        train_windows(&p, &ViewMasks::default(), &cfg, &windows, init.clone(), 9, ResumeState::default(), None, inside)
            .expect("trains");
    let stopped_between = train_windows(
        &p,
        &ViewMasks::default(),
        &cfg,
        &windows,
        init.clone(),
        9,
        ResumeState::default(),
        None,
        between,
    )
    .expect("trains");
    assert!(stopped_inside.interrupted && stopped_between.interrupted);
    assert_eq!(stopped_inside.windows.len(), 2);
    assert_eq!(stopped_inside.windows[1].learner.iteration, 17);
    assert_eq!(stopped_between.windows.len(), 1);

    for (stopped, running) in [(&stopped_inside, true), (&stopped_between, false)] {
        let n_done = if running { stopped.windows.len() - 1 } else { stopped.windows.len() };
        let resume = ResumeState {
            finished: stopped.windows[..n_done]
                .iter()
                .map(|w| (through_checkpoint(&w.learner, &init), w.report.clone()))
                .collect(),
            running: running.then(|| through_checkpoint(&stopped.windows[n_done].learner, &init)),
        };
        let mut trained_windows = Vec::new();
        let resumed = train_windows(&p, &ViewMasks::default(), &cfg, &windows, init.clone(), 9, resume, None, |e| {
            if let WindowEvent::Finished(w, _) = e {
                trained_windows.push(w.index);
            }
            ControlFlow::Continue(())
        })
        .expect("resumes");
        assert_eq!(trained_windows, [1], "only the unfinished window trains");
        assert!(!resumed.interrupted);
        for (a, b) in full.windows.iter().zip(&resumed.windows) {
            assert_eq!(a.learner.field.params(), b.learner.field.params(), "window {:?} differs", a.frames);
            assert_eq!(a.learner.losses, b.learner.losses);
            assert_eq!(a.learner.adam.m, b.learner.adam.m);
            assert_eq!((a.time_origin, &a.meta), (b.time_origin, &b.meta));
        }
    }
}

#[test]
fn a_shared_time_origin_lets_warm_starts_continue_the_previous_window() {
    // With each window's own origin the warm-started MLP sees its predecessor shifted by the
    // stride (here one frame); with the recording's origin, the shared frames keep their t'.
    // A window's first iteration trains its first frame, one the previous window trained too.
    let go = |_: WindowEvent<'_, MlpField>| ControlFlow::Continue(());
    let mut first_losses = Vec::new();
    for origin in [TimeOrigin::Window, TimeOrigin::Recording] {
        let (p, cfg, windows, init) = windowed_mlp(origin);
        let run = train_windows(&p, &ViewMasks::default(), &cfg, &windows, init, 9, ResumeState::default(), None, go)
            .expect("trains");
        let origins: Vec<f64> = run.windows.iter().map(|w| w.time_origin).collect();
        assert_eq!(origins, if origin == TimeOrigin::Window { [0.0, 1.0] } else { [0.0, 0.0] });
        first_losses.push((run.windows[1].learner.losses[0], run.windows[0].report.smoothed_loss));
    }
    let [(shifted, _), (aligned, end_of_first)] = first_losses[..] else { unreachable!() };
    assert!(aligned < 0.5 * shifted, "first loss of the warm window: aligned {aligned} vs shifted {shifted}");
    assert!(aligned < 3.0 * end_of_first, "aligned {aligned} vs the first window's end {end_of_first}");
}

/// A blob that travels 0.9 box units between the first and the last instant, so that at the
/// last instant it lies where the first instant's cameras see only dark pixels.
fn far_blob(p: DVec3, t: f64) -> f32 {
    let c = DVec3::new(-0.45 + 0.45 * t, 0.05, -0.05);
    (-(p - c).length_squared() / (2.0 * 0.15 * 0.15)).exp() as f32
}

#[test]
fn the_empty_space_hull_follows_a_flow_that_leaves_the_first_instant() {
    let settings = RenderSettings { supersample: 2, scale: 3.0, ..Default::default() };
    let times = [0.0, 1.0, 2.0];
    let mut views = Vec::new();
    for &t in &times {
        let field = move |p: Vec3, _: f64| far_blob(p.as_dvec3(), t);
        for camera in ring(6, 24) {
            let image = render_image(&field, &camera, &aabb(), &settings).expect("renders");
            views.push(View { camera, image, time: t });
        }
    }
    let p = Problem { aabb: aabb(), intensity_scale: 3.0, views, holdout: Vec::new(), time_step: 1.0 };
    let field_cfg = field_for_window(&FieldConfig::HashGrid(small_grid()), 3);
    let FieldConfig::HashGrid(grid) = &field_cfg else { unreachable!() };
    let init = HashGridField::new(grid, 4, 2).expect("field");
    let last_error = |skip_empty: bool| {
        let cfg = TrainConfig {
            occupancy: skip_empty.then(fluidnerf_neural::occupancy::OccupancyConfig::default),
            rays_per_image: 128,
            coarse_samples: 32,
            fine_samples: 0,
            ..quick(300, 1e-2)
        };
        let run = train_windows(
            &p,
            &ViewMasks::default(),
            &cfg,
            &WindowConfig::default(),
            init.clone(),
            3,
            ResumeState::default(),
            None,
            |_| ControlFlow::Continue(()),
        )
        .expect("trains");
        let field = StitchedField::from_run(&run).expect("stitches");
        let truth = Volume::from_fn([24, 24, 24], aabb(), |q| far_blob(q, 2.0));
        nrmse(&Volume::from_field([24, 24, 24], aabb(), &field, 2.0).data, &truth.data)
    };
    let (with_hull, without) = (last_error(true), last_error(false));
    assert!(without < 0.5, "without skipping the last instant is not reconstructed: NRMSE {without:.3}");
    assert!(
        with_hull <= without * 1.1 + 0.02,
        "the last instant with the hull (NRMSE {with_hull:.3}) is worse than without it ({without:.3})"
    );
}

/// Masks reach every window: a bright blotch (a reflection) in one camera at the last
/// instant ruins that instant unless its pixels are masked out.
#[test]
fn windows_leave_masked_pixels_out() {
    let settings = RenderSettings { supersample: 2, scale: 3.0, ..Default::default() };
    let times = [0.0, 1.0, 2.0];
    let mut views = Vec::new();
    let mut masks = Vec::new();
    for &t in &times {
        let field = move |p: Vec3, _: f64| far_blob(p.as_dvec3(), t);
        for (c, camera) in ring(6, 24).into_iter().enumerate() {
            let mut image = render_image(&field, &camera, &aabb(), &settings).expect("renders");
            let peak = image.min_max().1;
            let mut mask = None;
            if c == 0 && t == 2.0 {
                let mut m = vec![true; 24 * 24];
                for y in 6..18 {
                    for x in 6..18 {
                        image.data[y * 24 + x] = 4.0 * peak;
                        m[y * 24 + x] = false;
                    }
                }
                mask = Some(m);
            }
            views.push(View { camera, image, time: t });
            masks.push(mask);
        }
    }
    let p = Problem { aabb: aabb(), intensity_scale: 3.0, views, holdout: Vec::new(), time_step: 1.0 };
    let field_cfg = field_for_window(&FieldConfig::HashGrid(small_grid()), 3);
    let FieldConfig::HashGrid(grid) = &field_cfg else { unreachable!() };
    let init = HashGridField::new(grid, 4, 2).expect("field");
    let cfg = TrainConfig { rays_per_image: 128, coarse_samples: 32, fine_samples: 0, ..quick(250, 1e-2) };
    let last_error = |masks: &ViewMasks| {
        let go = |_: WindowEvent<'_, HashGridField>| ControlFlow::Continue(());
        let run =
            train_windows(&p, masks, &cfg, &WindowConfig::default(), init.clone(), 3, ResumeState::default(), None, go)
                .expect("trains");
        let field = StitchedField::from_run(&run).expect("stitches");
        let truth = Volume::from_fn([24, 24, 24], aabb(), |q| far_blob(q, 2.0));
        nrmse(&Volume::from_field([24, 24, 24], aabb(), &field, 2.0).data, &truth.data)
    };
    let masked = last_error(&ViewMasks { train: masks, holdout: Vec::new() });
    let unmasked = last_error(&ViewMasks::default());
    assert!(masked < 0.5 && masked < 0.6 * unmasked, "masked NRMSE {masked:.3}, unmasked {unmasked:.3}");
}

/// A window started from reconstructions of its instants ([`FrameStart`]) holds each instant's
/// own reconstruction at that instant's time before it has trained: here the exact blob at
/// each of three times, after one training iteration at a tenth of the rate, against a field
/// started uniform; and the frames' targets are not mixed up (each instant is nearer its own
/// blob than the others').
#[test]
fn a_window_starts_from_its_instants_reconstructions() {
    let times = [0.0, 1.0, 2.0];
    let p = problem(&times);
    let windows = WindowConfig { frames: 3, overlap: 0, ..WindowConfig::default() };
    let (_, init, cfg) = grid_windows_setup(3);
    let cfg = TrainConfig { max_iterations: 1, ..cfg };
    let target = |t: f64, points: &[Vec3], out: &mut [f32]| {
        for (o, p) in out.iter_mut().zip(points) {
            *o = blob(p.as_dvec3(), t);
        }
    };
    let start = FrameStart {
        target: &target,
        fit: fluidnerf_neural::start::StartFit { iterations: 300, points: 8192, learning_rate: 1e-2 },
        learning_rate_scale: 0.1,
        seconds: Vec::new(),
    };
    let run = |start: Option<&FrameStart>| {
        let run = train_windows(
            &p,
            &ViewMasks::default(),
            &cfg,
            &windows,
            init.clone(),
            5,
            ResumeState::default(),
            start,
            |_| ControlFlow::Continue(()),
        )
        .expect("trains");
        StitchedField::from_run(&run).expect("stitches")
    };
    let (started, fresh) = (run(Some(&start)), run(None));
    for t in times {
        let at = |f: &StitchedField, s: f64| Volume::from_field([24, 24, 24], aabb(), f, s).data;
        let (s, f) = (nrmse(&at(&started, t), &truth(t).data), nrmse(&at(&fresh, t), &truth(t).data));
        assert!(s < 0.15 && f > 0.5, "t = {t}: started {s:.3}, fresh {f:.3}");
        for other in times.iter().filter(|&&o| o != t) {
            let wrong = nrmse(&at(&started, t), &truth(*other).data);
            assert!(wrong > 2.0 * s, "t = {t} is nearer the blob of t = {other}: {wrong:.3} vs {s:.3}");
        }
    }
}

/// With `stop_per_frame` a window's stopping rule counts cycles through its frames: a rule
/// that holds as soon as it can be evaluated stops a three-frame window after
/// `(window + smoothing)` iterations without it and three times as many with it (and a
/// one-frame window alike either way).
#[test]
fn the_stopping_rule_counts_cycles_through_the_frames_when_asked() {
    let times = [0.0, 1.0, 2.0];
    let p = problem(&times);
    let run = |frames: usize, per_frame: bool| {
        let windows = WindowConfig { frames, overlap: 0, warm_start: false, ..WindowConfig::default() };
        let (_, init, cfg) = grid_windows_setup(frames);
        let cfg = TrainConfig {
            rays_per_image: 16,
            coarse_samples: 8,
            // The largest tolerance: any change of the smoothed loss short of doubling it (and a
            // falling loss's always) is within it.
            stop: StopRule { smoothing: 2, window: 3, tolerance: 1.0 },
            stop_per_frame: per_frame,
            ..cfg
        };
        let run =
            train_windows(&p, &ViewMasks::default(), &cfg, &windows, init, 1, ResumeState::default(), None, |_| {
                ControlFlow::Continue(())
            })
            .expect("trains");
        run.windows.iter().map(|w| (w.report.iterations, w.report.stop_reason)).collect::<Vec<_>>()
    };
    use fluidnerf_neural::train::StopReason::Converged;
    assert_eq!(run(3, false), [(5, Converged)]);
    assert_eq!(run(3, true), [(15, Converged)]);
    assert_eq!(run(1, true), [(5, Converged); 3]);
}
