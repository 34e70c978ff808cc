//! `fluidnerf info`: validates a scene and describes it (cameras, images, box coverage, time
//! steps, held-out frames, ground truth), listing every problem found.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;

use anyhow::{bail, Context};
use fluidnerf_core::{fixed, num, Camera, Frame, Scene};
use fluidnerf_io::image::read_image_with;
use fluidnerf_io::scene::{
    cameras_at_one_place, cameras_near_box, check_pixels, describe_one_place, load_scene, odd_sample_kind, recorded,
    scene_file_path,
};
use fluidnerf_io::volume::read_npy;

/// Validate a scene and describe it.
///
/// Reads the scene file (nerfstudio `transforms.json` with fluidnerf's `aabb`, `units`,
/// `truth`, ...), then every image and ground-truth volume, and prints: the reconstruction
/// box; per frame the camera centre, viewing direction, intrinsics (OpenCV convention: pixel
/// centres at integer coordinates, so cx, cy are 0.5 below the file's values), distortion and
/// thin lens, how much of the box the camera sees, and the image's size and value range; the
/// preprocessing the scene asks for (background, flat field, masks; with flat fields the range
/// of the normalised flats); the time steps, held-out frames and truth volumes. Problems (a
/// camera that misses the box, an image that is missing, unreadable, of the wrong size, with
/// NaN/Inf or negative pixels, or of another bit depth than the others, a background, flat
/// field or mask that does not fit its frame, a broken truth volume, one that is zero
/// throughout or one whose grid differs from the others) are listed at the end and make the
/// command exit with status 1; cameras close to the box are warned about. 8-bit images are
/// shown after the scene's `linearisation`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// The scene: a folder holding `transforms.json`, or the file itself.
    pub scene: PathBuf,
    /// Check the scene file only; do not read images and truth volumes.
    #[arg(long)]
    pub no_images: bool,
}

/// The share of an image's light on pixels whose rays miss the box above which `info` warns
/// ([`fluidnerf_pipeline::light_off_box`]).
const OFF_BOX_SHARE: f64 = 0.1;

fn v3(v: fluidnerf_core::glam::DVec3) -> String {
    // Round-off below the printed precision must not print as "-0.000".
    let c = |x: f64| if x.abs() < 5e-4 { 0.0 } else { x };
    format!("({}, {}, {})", fixed(c(v.x), 3), fixed(c(v.y), 3), fixed(c(v.z), 3))
}

fn describe_camera(out: &mut String, cam: &Camera, scene: &Scene) {
    let u = &scene.units;
    let k = &cam.intrinsics;
    let _ = writeln!(
        out,
        "  centre {} {u}, looking along {}, {} {u} from the box centre",
        v3(cam.centre()),
        v3(cam.forward()),
        fixed((scene.aabb.centre() - cam.centre()).length(), 3)
    );
    let _ = writeln!(
        out,
        "  intrinsics {}x{} px, fx {} fy {}, cx {} cy {} (pixel centres at integers), skew {}",
        k.width,
        k.height,
        num(k.fx),
        num(k.fy),
        num(k.cx),
        num(k.cy),
        num(k.skew)
    );
    let d = &cam.distortion;
    if d.is_identity() {
        let _ = writeln!(out, "  distortion: none");
    } else {
        let _ = writeln!(
            out,
            "  distortion (OpenCV): k1 {} k2 {} p1 {} p2 {} k3 {} k4 {} k5 {} k6 {}",
            num(d.k1),
            num(d.k2),
            num(d.p1),
            num(d.p2),
            num(d.k3),
            num(d.k4),
            num(d.k5),
            num(d.k6)
        );
    }
    if let Some(lens) = &cam.lens {
        let _ = writeln!(
            out,
            "  thin lens: f {} {u}, f/{} (aperture {} {u}), magnification {}, pixel pitch {} {u}, \
             focused at {} {u}",
            num(lens.focal_length),
            fixed(lens.f_number(), 3),
            fixed(lens.aperture_diameter, 4),
            num(lens.magnification),
            num(lens.pixel_pitch),
            fixed(lens.object_distance(), 3)
        );
    }
}

fn frame_title(i: usize, f: &Frame) -> String {
    let mut s = format!("frame {i}: {}", f.file_path.display());
    if let Some(name) = &f.camera_name {
        let _ = write!(s, "  camera {name}");
    }
    if let Some(t) = f.time {
        let _ = write!(s, "  time {t}");
    }
    if f.holdout {
        s.push_str("  [held out]");
    }
    s
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let file = scene_file_path(&args.scene);
    // A scene an import was stopped while putting into place is finished first.
    if let Some(dir) = file.parent() {
        super::import::settle_staging(dir, false)?;
    }
    let scene = load_scene(&args.scene).context("the scene is invalid")?;
    let mut out = String::new();
    let mut problems: Vec<String> = Vec::new();
    let mut warnings: Vec<String> = Vec::new();
    let u = scene.units.clone();
    let recording = recorded(&scene).context("the scene's preprocessing keys")?;
    let linearisation = recording.linearisation;

    let _ = writeln!(out, "scene {}", file.display());
    let _ = writeln!(
        out,
        "box {} .. {} {u} (size {} {u}), intensity_scale {}",
        v3(scene.aabb.min),
        v3(scene.aabb.max),
        v3(scene.aabb.size()),
        scene.intensity_scale
    );
    let _ = writeln!(out, "8-bit images: {linearisation}");
    let _ = writeln!(out, "preprocessing: {}", recording.describe());
    let names: std::collections::BTreeSet<&str> =
        scene.frames.iter().filter_map(|f| f.camera_name.as_deref()).collect();
    let times = scene.times();
    let held: Vec<usize> = scene.holdout_frames().map(|(i, _)| i).collect();
    let _ = writeln!(
        out,
        "{} frames, {} named cameras, {} time steps, {} held out",
        scene.frames.len(),
        names.len(),
        times.len(),
        held.len()
    );
    let _ = writeln!(out);

    for (i, d) in cameras_near_box(&scene) {
        warnings.push(format!(
            "frame {i} ({}): the camera is only {d:.3} {u} from the box; its rays through the box are \
             nearly as long as the box",
            scene.frames[i].file_path.display()
        ));
    }
    for found in cameras_at_one_place(&scene) {
        warnings.push(describe_one_place(&scene, &found));
    }
    let mut kinds = Vec::new();
    // Each image's total, after the background when the scene has one; None for a masked
    // image, whose total does not compare with the others'.
    let mut totals: Vec<Option<f64>> = vec![None; scene.frames.len()];
    // Each such image's darkest pixels, which tell an offset from a gain.
    let mut floors: Vec<Option<fluidnerf_pipeline::Floor>> = vec![None; scene.frames.len()];
    // Whether each image read has a pixel above 0 before any preprocessing.
    let mut lit = vec![false; scene.frames.len()];
    // The training images' noise readings ([`fluidnerf_core::Image::relative_noise`]).
    let mut noise_levels = Vec::new();
    // Whether a training (not held-out) image has a pixel above 0, before any preprocessing.
    let mut training_lit = false;
    // Each image's light on pixels whose rays miss the box: of the image as read, then of what
    // a run trains on (after the background, inside the mask) when the scene preprocesses.
    let mut off_box: Vec<Option<fluidnerf_pipeline::OffBox>> = vec![None; scene.frames.len()];
    // Each image's one value, when every pixel (a run uses) holds the same: as read, then as
    // preprocessed.
    let mut levels: Vec<Option<f32>> = vec![None; scene.frames.len()];
    let bar = crate::progress::bar(scene.frames.len() as u64, "checking");
    for (i, f) in scene.frames.iter().enumerate() {
        let _ = writeln!(out, "{}", frame_title(i, f));
        describe_camera(&mut out, &f.camera, &scene);
        let vis = f.camera.visibility(&scene.aabb);
        let _ = writeln!(
            out,
            "  sees {:.1}% of the box; {:.1}% of its pixels look through the box",
            100.0 * vis.box_fraction_in_view,
            100.0 * vis.pixel_fraction_on_box
        );
        if vis.box_fraction_in_view < 1.0 {
            warnings.push(format!(
                "frame {i} ({}): the camera sees only {:.1}% of the box",
                f.file_path.display(),
                100.0 * vis.box_fraction_in_view
            ));
        }
        if !args.no_images {
            let path = scene.resolve(&f.file_path);
            match read_image_with(&path, linearisation) {
                Err(e) => {
                    let _ = writeln!(out, "  image: ERROR {e}");
                    problems.push(format!("frame {i}: {e}"));
                }
                Ok((img, kind)) => {
                    kinds.push((i, kind));
                    totals[i] = Some(img.sum());
                    floors[i] = Some(fluidnerf_pipeline::Floor::of(&img.data));
                    lit[i] = img.data.iter().any(|&v| v > 0.0);
                    let (w, h) = (f.camera.width(), f.camera.height());
                    let (lo, hi) = img.min_max();
                    let mean = img.sum() / img.data.len().max(1) as f64;
                    let noise = img.relative_noise();
                    if !f.holdout {
                        noise_levels.extend(noise);
                        training_lit |= hi > 0.0;
                    }
                    let noise = noise.map_or("not estimated".into(), |n| format!("{:.2} % of the range", 100.0 * n));
                    let _ = writeln!(
                        out,
                        "  image {}x{} {kind}, values {lo} .. {hi}, mean {mean:.4}, noise {noise}",
                        img.width, img.height
                    );
                    if hi <= 0.0 {
                        warnings.push(format!(
                            "frame {i} ({}): the image is black (every pixel 0); it carves everything it sees \
                             out of the volume",
                            f.file_path.display()
                        ));
                    }
                    off_box[i] = fluidnerf_pipeline::light_off_box(&f.camera, &img, &scene.aabb);
                    levels[i] = fluidnerf_pipeline::one_value_throughout(&img.data, None);
                    let saturated = kind.saturated(&img);
                    if saturated > 0 {
                        warnings.push(format!(
                            "frame {i} ({}): {saturated} pixel(s) at the {kind} full scale; a saturated pixel \
                             recorded less light than arrived, so the line-integral model does not hold there: \
                             mask them (mask_path) or record with less exposure",
                            f.file_path.display()
                        ));
                    }
                    if (img.width, img.height) != (w, h) {
                        problems.push(format!(
                            "frame {i}: {}: image is {}x{} pixels but the frame's intrinsics say {w}x{h}",
                            path.display(),
                            img.width,
                            img.height
                        ));
                    }
                    if let Some((col, row)) = img.first_non_finite() {
                        let n = img.data.iter().filter(|v| !v.is_finite()).count();
                        problems.push(format!(
                            "frame {i}: {}: {n} non-finite pixel(s), the first at (col {col}, row {row}) is {}",
                            path.display(),
                            img.get(col, row)
                        ));
                    } else if let Err(e) = check_pixels(&path, &img) {
                        problems.push(format!("frame {i}: {e}"));
                    }
                }
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let only_kinds: Vec<_> = kinds.iter().map(|k| k.1).collect();
    if let Some((at, kind, usual)) = odd_sample_kind(&only_kinds) {
        let i = kinds[at].0;
        problems.push(format!(
            "frame {i}: {}: {} image among {usual} ones; {}",
            scene.resolve(&scene.frames[i].file_path).display(),
            kind.with_article(),
            fluidnerf_io::scene::different_scales(kind, usual)
        ));
    }
    // Backgrounds, flat fields and masks, read as a run reads them, once the images themselves
    // are sound.
    if !args.no_images && problems.is_empty() && recording.preprocesses() {
        match fluidnerf_io::scene::load_preprocessed_with(&scene, recording.clone()) {
            Err(e) => problems.push(format!("preprocessing: {e}")),
            // What a run trains on: the pixels left after the background, inside the masks.
            Ok(p) => {
                if let Some((lo, hi)) = p.flat_range {
                    let _ = writeln!(
                        out,
                        "flat fields (normalised to mean 1 over the used pixels): {lo:.3} .. {hi:.3}; the images \
                         are divided by them"
                    );
                }
                for (i, (im, m)) in p.images.iter().zip(&p.masks).enumerate() {
                    levels[i] = fluidnerf_pipeline::one_value_throughout(&im.data, m.as_deref());
                    off_box[i] = match m {
                        None => fluidnerf_pipeline::light_off_box(&scene.frames[i].camera, im, &scene.aabb),
                        Some(m) => {
                            let mut used = im.clone();
                            used.data.iter_mut().zip(m).filter(|(_, &keep)| !keep).for_each(|(v, _)| *v = 0.0);
                            fluidnerf_pipeline::light_off_box(&scene.frames[i].camera, &used, &scene.aabb)
                        }
                    };
                    totals[i] = m.is_none().then(|| im.sum());
                    floors[i] = m.is_none().then(|| fluidnerf_pipeline::Floor::of(&im.data));
                    // A run warns of it as it starts; here it is one of the scene's warnings.
                    if lit[i] && im.data.iter().all(|&v| v == 0.0) {
                        warnings.push(format!(
                            "frame {i} ({}): nothing is left after its background is subtracted (every pixel at or \
                             below it), so a run reads it as black, as empty space along every ray of its camera; \
                             check the frame's background",
                            scene.frames[i].file_path.display()
                        ));
                    }
                }
                // A run reads the noise of the images it trains on, after the background and
                // the flat field: the background's own offset and noise change the reading.
                noise_levels = scene
                    .frames
                    .iter()
                    .zip(&p.images)
                    .filter(|(f, _)| !f.holdout)
                    .filter_map(|(_, im)| im.relative_noise())
                    .collect();
                training_lit = scene.frames.iter().enumerate().filter(|(_, f)| !f.holdout).any(|(i, _)| {
                    let lit = p.images[i].data.iter().enumerate().filter(|&(_, &v)| v > 0.0);
                    lit.map(|(k, _)| k).any(|k| p.masks[i].as_ref().is_none_or(|m| m[k]))
                })
            }
        }
    }
    // Refused by every run: info said "no problems found".
    if !args.no_images && problems.is_empty() {
        if let Some(why) = fluidnerf_pipeline::flat_training_images(&scene, &levels) {
            problems.push(why);
        }
    }
    // The largest share, for a scene whose images all lie where they should.
    if let Some((i, off)) =
        off_box.iter().enumerate().filter_map(|(i, o)| o.map(|o| (i, o))).max_by(|a, b| a.1.share.total_cmp(&b.1.share))
    {
        let _ = writeln!(
            out,
            "light on pixels whose rays miss the box: at most {:.1}% of an image's (frame {i})",
            100.0 * off.share
        );
    }
    for (i, off) in off_box.iter().enumerate() {
        if let Some(off) = off.filter(|o| o.share > OFF_BOX_SHARE && o.pixels >= 10) {
            warnings.push(format!(
                "frame {i} ({}): {:.0}% of the image's light ({} of its {} lit pixels) lies on pixels whose rays \
                 miss the box, light no reconstruction can explain (a run drops those rays): the camera's \
                 calibration (focal length, pose) or the box may be wrong, or something bright outside the box is \
                 in view (mask it, or subtract a background)",
                scene.frames[i].file_path.display(),
                100.0 * off.share,
                off.pixels,
                off.lit
            ));
        }
    }
    if let Some(median) = fluidnerf_core::image::median_noise(noise_levels) {
        let clean = fluidnerf_core::image::reads_clean(Some(median));
        // A scene of several instants is reconstructed by tr-fast by default, which starts
        // from no voxel run; a static one by the hybrid, which starts from one.
        let reads = match (clean, times.len() > 1) {
            (true, false) => "clean: automatic settings start from ASART, rays over each pixel's area",
            (false, false) => "noisy: automatic settings start from SART-TV, one ray per pixel",
            (true, true) => {
                "clean: automatic settings draw rays over each pixel's area (a --start-method auto run per \
                             instant would be ASART)"
            }
            (false, true) => {
                "noisy: automatic settings draw one ray per pixel (a --start-method auto run per instant \
                              would be SART-TV)"
            }
        };
        let _ = writeln!(
            out,
            "training images' noise (median of the estimates): {:.2} % of their range, {reads}",
            100.0 * median
        );
    }
    // Every run refuses such a scene: say so here, not only when a run starts.
    let training = scene.frames.iter().any(|f| !f.holdout);
    if !training {
        problems.push(
            "every frame is held out (`holdout`), so no image is left to reconstruct from; train on some of \
             them"
                .to_string(),
        );
    }
    if !args.no_images && problems.is_empty() && training && !training_lit {
        problems.push(fluidnerf_core::image::ALL_BLACK.to_string());
    }
    // What a run without gains would warn of: cameras whose images' totals differ.
    if !args.no_images && problems.is_empty() {
        warnings.extend(fluidnerf_pipeline::gain_hint(&scene, &totals, &floors));
    }
    let _ = writeln!(out);

    if times.is_empty() {
        let _ = writeln!(out, "time steps: none (static scene)");
    } else {
        let list: Vec<String> = times.iter().map(|t| t.to_string()).collect();
        let _ = writeln!(out, "time steps: {}", list.join(", "));
    }
    if held.is_empty() {
        let _ = writeln!(out, "held-out frames: none");
    } else {
        let list: Vec<String> = held.iter().map(|i| i.to_string()).collect();
        let _ = writeln!(out, "held-out frames: {}", list.join(", "));
    }
    if scene.truth.is_empty() {
        let _ = writeln!(out, "truth volumes: none");
    }
    let mut truth_dims: Option<[usize; 3]> = None;
    for t in &scene.truth {
        let path = scene.resolve(&t.file_path);
        let when = t.time.map_or(String::new(), |t| format!(" (time {t})"));
        if args.no_images {
            let _ = writeln!(out, "truth{when}: {}", path.display());
            continue;
        }
        match read_npy(&path, scene.aabb) {
            Ok(v) => {
                let (lo, hi) = v.min_max();
                let [nx, ny, nz] = v.dims;
                let _ = writeln!(out, "truth{when}: {} {nx}x{ny}x{nz} voxels, values {lo} .. {hi}", path.display());
                if !(lo.is_finite() && hi.is_finite()) {
                    problems.push(format!("truth {}: has NaN or infinite values", path.display()));
                } else if lo == 0.0 && hi == 0.0 {
                    // eval refuses it; a run's NRMSE against it is NaN.
                    problems.push(format!(
                        "truth {}: every voxel is zero, so the NRMSE against it (relative to the truth's norm) is \
                         undefined; give a truth that holds the field",
                        path.display()
                    ));
                } else if lo < 0.0 {
                    // Emission is never negative: scores against such a truth reward negative values.
                    let count = v.data.iter().filter(|&&x| x < 0.0).count();
                    warnings.push(format!(
                        "truth {}: {count} voxel(s) are negative (down to {lo}); light emitted or absorbed is never \
                         negative, and the metrics against it would reward negative reconstructions there",
                        path.display()
                    ));
                }
                match truth_dims {
                    Some([a, b, c]) if [a, b, c] != v.dims => problems.push(format!(
                        "truth {}: {nx}x{ny}x{nz} voxels, but the first truth volume has {a}x{b}x{c}",
                        path.display()
                    )),
                    _ => truth_dims = Some(v.dims),
                }
            }
            Err(e) => {
                let _ = writeln!(out, "truth{when}: ERROR {e}");
                problems.push(format!("truth: {e}"));
            }
        }
    }
    if let Some(message) = fluidnerf_pipeline::unmatched_truth(&scene) {
        warnings.push(message);
    }
    if let Some(message) = fluidnerf_pipeline::instants_short_of_cameras(&scene) {
        warnings.push(message);
    }
    if let Some(message) = fluidnerf_pipeline::truth_gaps(&scene) {
        warnings.push(message);
    }
    if let Some(message) = fluidnerf_pipeline::timeless_truth(&scene) {
        warnings.push(message);
    }
    if times.len() > 1 {
        for &t in &times {
            if !scene.training_frames().any(|(_, f)| f.time == Some(t)) {
                warnings.push(format!("time {t} has no training frames (all held out)"));
            }
        }
    }

    let _ = writeln!(out);
    for w in &warnings {
        let _ = writeln!(out, "warning: {w}");
    }
    for p in &problems {
        let _ = writeln!(out, "problem: {p}");
    }
    if problems.is_empty() {
        let _ = writeln!(out, "no problems found");
    }
    std::io::stdout().lock().write_all(out.as_bytes()).context("cannot write to stdout")?;
    if !problems.is_empty() {
        bail!("{} problem(s) found in {}; the first: {}", problems.len(), file.display(), problems[0]);
    }
    Ok(())
}
