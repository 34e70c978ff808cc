//! Agisoft Metashape camera exports (File › Export › Export Cameras…, "Agisoft XML"), the file
//! nerfstudio's `ns-process-data metashape` reads too.
//!
//! # The file
//! `<document><chunk>` (one chunk) holding
//! - `<sensors>`: `<sensor id type="frame">` with `<resolution width height/>` and a
//!   `<calibration type="frame" class="adjusted">` (preferred) or `class="initial"` (used when no
//!   adjusted one is given, which is the case for a calibration fixed before alignment) with its
//!   own `<resolution>`, `<f>`, `<cx>`, `<cy>`, `<b1>`, `<b2>`, `<k1>`…`<k4>`, `<p1>`…`<p4>`
//!   (absent terms are zero);
//! - `<cameras>`: `<camera id label sensor_id [component_id] [enabled]>` with a `<transform>`,
//!   possibly inside `<group>` elements (folders, stations);
//! - the chunk's `<transform>` (`<rotation>` 9 numbers row-major, `<translation>` 3, `<scale>`
//!   1), or, as Metashape 2 writes it, one per `<components><component id>`, named by the
//!   cameras' `component_id`.
//!
//! # Conventions, and how they are converted
//! - **Camera axes** are OpenCV's (x right, y down, z forward): taken as they are.
//! - **Pose**: a camera's `<transform>` is 16 numbers, a row-major 4 × 4 rigid transform from
//!   the camera to the chunk's internal frame. The chunk transform maps that frame to the
//!   chunk's coordinate system, `x_world = scale · R x_chunk + t` (Metashape's
//!   `chunk.transform.matrix`). A camera's `world_from_camera` is then the rotation `R R_cam`
//!   and the centre `scale · R t_cam + t`: a uniform scale changes where the camera stands but
//!   not what it sees, so the pose stays rigid. Without any transform the internal frame is the
//!   world (its scale is arbitrary).
//! - **Pixels**: Metashape's image coordinates put the top-left pixel's centre at (0.5, 0.5)
//!   and its `cx`, `cy` are offsets of the principal point from the image centre, so
//!   `cx_core = width / 2 + cx − 0.5` (same for y), as Agisoft's own COLMAP export writes
//!   `cx + width / 2` for COLMAP, whose pixel centres are at +0.5 too.
//! - **Projection** (Metashape manual, appendix "Camera models", frame cameras):
//!   `x' = x (1 + K1 r² + K2 r⁴ + K3 r⁶ + K4 r⁸) + (P1 (r² + 2x²) + 2 P2 x y)(1 + P3 r² + P4 r⁴)`,
//!   `y' = y (1 + …) + (P2 (r² + 2y²) + 2 P1 x y)(1 + P3 r² + P4 r⁴)`,
//!   `u = w/2 + cx + x' (f + B1) + y' B2`, `v = h/2 + cy + y' f`.
//!   OpenCV's tangential terms are `2 p1 x y + p2 (r² + 2x²)` in x and `p1 (r² + 2y²) + 2 p2 x y`
//!   in y: Metashape's `P1` is OpenCV's `p2` and its `P2` is OpenCV's `p1`, so the two are
//!   swapped on reading. The radial terms are OpenCV's `k1 k2 k3`. `B1` and `B2` are exactly
//!   the intrinsics' `fx − fy` and `skew`: `fx = f + B1`, `fy = f`, `skew = B2`.
//! - **Units**: the chunk's coordinate system is metric (Metashape's local coordinates and the
//!   geocentric frame of a georeferenced chunk are in metres), so a file with a chunk (or
//!   component) transform gives the world in metres ([`MetashapeCameras::units`]); without one
//!   the scale is arbitrary and no unit is given.
//!
//! # What is refused
//! Every message names the file, and the camera (by label) or the sensor (by id and label) and
//! the element. Refused: a root other than `<document>`, other than one `<chunk>`, sensors of
//! other types than `frame` (fisheye, spherical, cylindrical, RPC) and terms the camera model
//! does not hold (`k4`, `p3`, `p4` other than zero), calibrations in PhotoScan 1.2's form
//! (`<fx>`, `<fy>`, `<skew>`, with an absolute principal point and OpenCV's tangential order),
//! a camera whose `sensor_id` or `component_id` names nothing, a `<transform>` that is not 16
//! numbers or not rigid, a chunk rotation that is not a rotation or a scale that is not
//! positive, numbers that do not parse or are not finite, a label or id given twice, and
//! secondary cameras of a multi-camera system without a pose of their own (their pose is their
//! master's and their sensor's offset, which is not read). Sensors that no enabled, aligned
//! camera uses are not checked.
//!
//! Cameras with `enabled="false"` are left out ([`MetashapeCameras::disabled`]); cameras without a
//! `<transform>` (not aligned) are listed in [`MetashapeCameras::unaligned`] for the caller to
//! refuse or leave out.

use std::collections::HashMap;
use std::path::Path;

use fluidnerf_core::glam::{DAffine3, DMat3, DVec3};
use fluidnerf_core::{num, Camera, Distortion, Intrinsics};

use crate::IoError;

/// The cameras of a Metashape camera export.
#[derive(Clone, Debug, PartialEq)]
pub struct MetashapeCameras {
    /// The enabled, aligned cameras by label, in the file's order.
    pub cameras: Vec<(String, Camera)>,
    /// Labels of the enabled cameras without a pose (not aligned in Metashape).
    pub unaligned: Vec<String>,
    /// Labels of the disabled cameras (`enabled="false"`), left out.
    pub disabled: Vec<String>,
    /// The world's length unit: `Some("m")` when a chunk or component transform placed the
    /// cameras in the chunk's coordinate system, `None` when the file gives no transform and
    /// the cameras stand in Metashape's internal frame, whose scale is arbitrary.
    pub units: Option<&'static str>,
}

/// The element children of `node` named `name`.
fn children<'a, 'input>(node: roxmltree::Node<'a, 'input>, name: &str) -> Vec<roxmltree::Node<'a, 'input>> {
    node.children().filter(|c| c.is_element() && c.tag_name().name() == name).collect()
}

/// The one child of `node` named `name`, or none; `what` names `node` in the error about two.
fn child<'a, 'input>(
    node: roxmltree::Node<'a, 'input>,
    name: &str,
    what: &str,
) -> Result<Option<roxmltree::Node<'a, 'input>>, String> {
    match children(node, name).as_slice() {
        [] => Ok(None),
        [one] => Ok(Some(*one)),
        [_, second, ..] => Err(format!("{what}: `<{name}>` appears twice (line {})", super::doc_line(*second))),
    }
}

/// The whitespace-separated numbers of an element's text, each finite; `what` names the element.
fn numbers(node: roxmltree::Node<'_, '_>, what: &str) -> Result<Vec<f64>, String> {
    let text: String = node.children().filter(|n| n.is_text()).filter_map(|n| n.text()).collect();
    text.split_whitespace()
        .map(|s| match s.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => {
                Err(format!("{what}: `{}` is not a finite number (line {})", super::excerpt(s), super::doc_line(node)))
            }
        })
        .collect()
}

/// Exactly `n` numbers (`shape` says what they are) of an element's text.
fn sized(node: roxmltree::Node<'_, '_>, what: &str, n: usize, shape: &str) -> Result<Vec<f64>, String> {
    let v = numbers(node, what)?;
    if v.len() != n {
        return Err(format!(
            "{what} has {} number(s); expected {n} ({shape}) (line {})",
            v.len(),
            super::doc_line(node)
        ));
    }
    Ok(v)
}

/// `<resolution width height/>` as positive integers.
fn resolution(node: roxmltree::Node<'_, '_>, what: &str) -> Result<(u32, u32), String> {
    let side = |key: &str| -> Result<u32, String> {
        let text = node.attribute(key).ok_or_else(|| format!("{what}: `<resolution>` has no `{key}`"))?;
        text.trim().parse::<u32>().ok().filter(|&v| v > 0).ok_or_else(|| {
            format!("{what}: `<resolution>` `{key}` is `{}`; expected a positive integer", super::excerpt(text))
        })
    };
    Ok((side("width")?, side("height")?))
}

/// A 3 × 3 row-major matrix.
fn rows(m: &[f64]) -> DMat3 {
    DMat3::from_cols_array(&[m[0], m[3], m[6], m[1], m[4], m[7], m[2], m[5], m[8]])
}

/// `m` as a rotation: as it is, or the nearest rotation when `m` is one up to the rounding of
/// few written digits (said in a warning); `what` names it.
fn rotation(path: &Path, m: DMat3, what: &str) -> Result<DMat3, String> {
    if let Some((nearest, error)) = fluidnerf_core::camera::rounded_rotation(m) {
        log::warn!(
            "{}: {what} is a rotation only to within {error:.1e} (written with few digits?); the nearest rotation \
             is used",
            path.display()
        );
        return Ok(nearest);
    }
    let error = fluidnerf_core::camera::orthonormality_error(m);
    if error > fluidnerf_core::camera::ROTATION_TOLERANCE || m.determinant() <= 0.0 {
        return Err(format!(
            "{what} is not a rotation (orthonormality error {error:.1e}, determinant {})",
            num(m.determinant())
        ));
    }
    Ok(m)
}

/// A chunk's or component's `<transform>` (`<rotation>`, `<translation>`, `<scale>`, each
/// optional) as `world_from_chunk`, `x ↦ scale · R x + t`.
fn chunk_transform(path: &Path, node: roxmltree::Node<'_, '_>, what: &str) -> Result<DAffine3, String> {
    let part = |name: &str| child(node, name, what);
    let r = match part("rotation")? {
        Some(n) => rows(&sized(n, &format!("{what}: `<rotation>`"), 9, "a 3 × 3 matrix, row by row")?),
        None => DMat3::IDENTITY,
    };
    let r = rotation(path, r, &format!("{what}: `<rotation>`"))?;
    let t = match part("translation")? {
        Some(n) => DVec3::from_slice(&sized(n, &format!("{what}: `<translation>`"), 3, "x y z")?),
        None => DVec3::ZERO,
    };
    let scale = match part("scale")? {
        Some(n) => sized(n, &format!("{what}: `<scale>`"), 1, "one number")?[0],
        None => 1.0,
    };
    // Metashape's scales are metres per internal unit, near 1; beyond 10^±100 its cube, which
    // placing the cameras takes, under- or overflows.
    if !(1e-100..=1e100).contains(&scale) {
        let why = if scale > 0.0 { "between 1e-100 and 1e100" } else { "positive" };
        return Err(format!("{what}: `<scale>` is {}; a chunk's scale must be {why}", num(scale)));
    }
    Ok(DAffine3::from_mat3_translation(r * scale, t))
}

/// A sensor's calibration as intrinsics and OpenCV distortion, or why it cannot be used.
fn sensor_camera(path: &Path, sensor: roxmltree::Node<'_, '_>, what: &str) -> Result<(Intrinsics, Distortion), String> {
    match sensor.attribute("type") {
        Some("frame") => {}
        Some(other) => {
            return Err(format!(
                "{what} is of type `{}`; only `frame` sensors (pinhole cameras with Brown distortion) are read: \
                 fisheye, spherical, cylindrical and RPC sensors project otherwise",
                super::excerpt(other)
            ))
        }
        None => return Err(format!("{what} has no `type`; expected `frame`")),
    }
    let calibrations = children(sensor, "calibration");
    let of_class = |class: &str| -> Result<Option<roxmltree::Node<'_, '_>>, String> {
        match calibrations.iter().filter(|c| c.attribute("class") == Some(class)).collect::<Vec<_>>().as_slice() {
            [] => Ok(None),
            [one] => Ok(Some(**one)),
            [_, second, ..] => Err(format!(
                "{what}: two `<calibration class=\"{class}\">` (the second on line {})",
                super::doc_line(**second)
            )),
        }
    };
    let calibration = match (of_class("adjusted")?, of_class("initial")?) {
        (Some(adjusted), _) => adjusted,
        (None, Some(initial)) => {
            log::info!("{}: {what} has no adjusted calibration; its initial one is used", path.display());
            initial
        }
        (None, None) => match calibrations.as_slice() {
            [only] => *only,
            [] => {
                return Err(format!(
                    "{what} has no `<calibration>`: it was not calibrated (align the photos in Metashape, or load \
                     a calibration for it, before exporting the cameras)"
                ))
            }
            _ => {
                return Err(format!(
                    "{what} has {} `<calibration>` elements and none of class `adjusted` or `initial`",
                    calibrations.len()
                ))
            }
        },
    };
    let class = calibration.attribute("class").unwrap_or("unclassed");
    let what = format!("{what}: {class} `<calibration>`");
    if let Some(kind) = calibration.attribute("type").filter(|t| *t != "frame") {
        return Err(format!("{what} is of type `{}`; only `frame` calibrations are read", super::excerpt(kind)));
    }
    let sensor_size = child(sensor, "resolution", &what)?.map(|n| resolution(n, &what)).transpose()?;
    let own_size = child(calibration, "resolution", &what)?.map(|n| resolution(n, &what)).transpose()?;
    let (width, height) = match (sensor_size, own_size) {
        (Some(s), Some(c)) if s != c => {
            return Err(format!(
                "{what} is for {}x{} images but the sensor's are {}x{}; export the cameras at the images' resolution",
                c.0, c.1, s.0, s.1
            ))
        }
        (_, Some(size)) | (Some(size), None) => size,
        (None, None) => return Err(format!("{what}: no `<resolution>`, here or in the sensor")),
    };
    let mut terms: HashMap<&str, f64> = HashMap::new();
    for node in calibration.children().filter(roxmltree::Node::is_element) {
        let name = node.tag_name().name();
        if name == "fx" || name == "fy" || name == "skew" {
            return Err(format!(
                "{what} gives `<{name}>`, as PhotoScan 1.2 and older wrote calibrations (an absolute principal \
                 point, OpenCV's order of the tangential terms): open the project in a current Metashape and export \
                 the cameras again"
            ));
        }
        let known = ["f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2", "p3", "p4"];
        let Some(key) = known.iter().find(|k| **k == name) else { continue };
        let v = sized(node, &format!("{what}: `<{name}>`"), 1, "one number")?[0];
        if terms.insert(key, v).is_some() {
            return Err(format!("{what}: `<{name}>` appears twice (line {})", super::doc_line(node)));
        }
    }
    let term = |k: &str| terms.get(k).copied().unwrap_or(0.0);
    for k in ["k4", "p3", "p4"] {
        if term(k) != 0.0 {
            return Err(format!(
                "{what}: `<{k}>` is {}; the camera model (OpenCV's k1 k2 k3 p1 p2, with skew) has no such term: \
                 calibrate with {k} fixed at zero in Metashape (Tools › Camera Calibration) and export again",
                num(term(k))
            ));
        }
    }
    let Some(&f) = terms.get("f") else { return Err(format!("{what}: no `<f>` (focal length in pixels)")) };
    let intrinsics = Intrinsics {
        width,
        height,
        fx: f + term("b1"),
        fy: f,
        cx: f64::from(width) / 2.0 + term("cx") - 0.5,
        cy: f64::from(height) / 2.0 + term("cy") - 0.5,
        skew: term("b2"),
    };
    intrinsics.validate().map_err(|e| format!("{what}: {e}"))?;
    if let Some(why) = super::principal_point_outside(&intrinsics) {
        log::warn!("{}: {what}: {why}", path.display());
    }
    // Metashape's P1 multiplies r² + 2x² in x, as OpenCV's p2 does; its P2 is OpenCV's p1.
    let distortion = Distortion {
        k1: term("k1"),
        k2: term("k2"),
        k3: term("k3"),
        p1: term("p2"),
        p2: term("p1"),
        ..Default::default()
    };
    Ok((intrinsics, distortion))
}

/// `enabled` as Metashape writes it (`true`/`false`, older files `1`/`0`); absent is enabled.
fn enabled(camera: roxmltree::Node<'_, '_>, what: &str) -> Result<bool, String> {
    match camera.attribute("enabled").map(str::trim) {
        None | Some("true" | "1") => Ok(true),
        Some("false" | "0") => Ok(false),
        Some(other) => Err(format!("{what}: `enabled` is `{}`; expected true or false", super::excerpt(other))),
    }
}

/// A camera's `<transform>` as `chunk_from_camera`: 16 numbers, row-major, rigid.
fn camera_transform(path: &Path, node: roxmltree::Node<'_, '_>, what: &str) -> Result<DAffine3, String> {
    let what = format!("{what}: `<transform>`");
    let m = sized(node, &what, 16, "a 4 × 4 matrix, row by row")?;
    if [m[12], m[13], m[14], m[15] - 1.0].iter().any(|v| v.abs() > 1e-9) {
        return Err(format!(
            "{what}: the last row is {} {} {} {}; a camera's transform ends with 0 0 0 1",
            num(m[12]),
            num(m[13]),
            num(m[14]),
            num(m[15])
        ));
    }
    let r = rows(&[m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]]);
    let r = rotation(path, r, &format!("{what}'s 3 × 3 part"))
        .map_err(|e| format!("{e}; a camera's transform is rigid"))?;
    Ok(DAffine3::from_mat3_translation(r, DVec3::new(m[3], m[7], m[11])))
}

/// `world_from_camera` of a camera at `chunk_from_camera` in a chunk placed by `world_from_chunk`
/// (`scale · R x + t`): rotation `R R_cam`, centre `world_from_chunk(t_cam)`; the scale moves
/// the centre only.
fn world_from_camera(world_from_chunk: &DAffine3, chunk_from_camera: &DAffine3) -> DAffine3 {
    let m = world_from_chunk.matrix3;
    let scale = m.determinant().cbrt();
    DAffine3::from_mat3_translation(
        (m * (1.0 / scale)) * chunk_from_camera.matrix3,
        world_from_chunk.transform_point3(chunk_from_camera.translation),
    )
}

/// Reads a Metashape camera export (see the module docs for the format and its conventions).
pub fn read_metashape(path: &Path) -> Result<MetashapeCameras, IoError> {
    let text = crate::read_input_text(path, "Metashape camera file")?;
    let bad = |why: String| IoError::invalid(path, why);
    // The XML parser recurses per element: refuse absurd nesting before it sees it.
    if super::xml_nesting(&text) > 64 {
        return Err(bad("elements nested more than 64 deep; not a Metashape camera file".into()));
    }
    let doc = roxmltree::Document::parse(&text).map_err(|e| bad(format!("malformed XML: {e}")))?;
    let root = doc.root_element();
    if root.tag_name().name() != "document" {
        return Err(bad(format!(
            "the root element is `<{}>`; a Metashape camera export (Agisoft XML) has `<document>`",
            root.tag_name().name()
        )));
    }
    let chunk = match children(root, "chunk").as_slice() {
        [one] => *one,
        [] => return Err(bad("no `<chunk>` in `<document>`; not a Metashape camera export".into())),
        many => {
            return Err(bad(format!(
                "{} chunks in one file; export the cameras of one chunk (the active one) per file",
                many.len()
            )))
        }
    };

    // Sensors by id; each one's calibration is read only if a camera uses it.
    let mut sensors: Vec<(&str, String, roxmltree::Node<'_, '_>)> = Vec::new();
    if let Some(list) = child(chunk, "sensors", "`<chunk>`").map_err(bad)? {
        for s in children(list, "sensor") {
            let Some(id) = s.attribute("id") else {
                return Err(bad(format!("a `<sensor>` without an `id` (line {})", super::doc_line(s))));
            };
            let what = match s.attribute("label") {
                Some(label) => format!("sensor {id} (`{label}`)"),
                None => format!("sensor {id}"),
            };
            if sensors.iter().any(|(other, _, _)| *other == id) {
                return Err(bad(format!("{what}: the sensor id {id} appears twice (line {})", super::doc_line(s))));
            }
            sensors.push((id, what, s));
        }
    }
    let mut calibrated: HashMap<&str, (Intrinsics, Distortion)> = HashMap::new();

    let chunk_world = child(chunk, "transform", "`<chunk>`")
        .map_err(bad)?
        .map(|t| chunk_transform(path, t, "the chunk's `<transform>`"))
        .transpose()
        .map_err(bad)?;
    let mut components: Vec<(&str, Option<DAffine3>)> = Vec::new();
    if let Some(list) = child(chunk, "components", "`<chunk>`").map_err(bad)? {
        for c in children(list, "component") {
            let Some(id) = c.attribute("id") else {
                return Err(bad(format!("a `<component>` without an `id` (line {})", super::doc_line(c))));
            };
            let what = format!("component {id}");
            if components.iter().any(|(other, _)| *other == id) {
                return Err(bad(format!("{what}: the component id appears twice (line {})", super::doc_line(c))));
            }
            let transform = child(c, "transform", &what)
                .map_err(bad)?
                .map(|t| chunk_transform(path, t, &format!("{what}'s `<transform>`")))
                .transpose()
                .map_err(bad)?;
            components.push((id, transform));
        }
    }

    let Some(cameras) = child(chunk, "cameras", "`<chunk>`").map_err(bad)? else {
        return Err(bad("the chunk has no `<cameras>`".into()));
    };
    let mut out = MetashapeCameras { cameras: Vec::new(), unaligned: Vec::new(), disabled: Vec::new(), units: None };
    let mut seen: Vec<(&str, &str)> = Vec::new();
    // Whether the cameras stand in the chunk's coordinate system (a transform placed them), and
    // the first camera, to name when another one does not.
    let mut placed: Option<(bool, String)> = None;
    for cam in cameras.descendants().filter(|n| n.is_element() && n.tag_name().name() == "camera") {
        let line = super::doc_line(cam);
        let Some(label) = cam.attribute("label").filter(|l| !l.trim().is_empty()) else {
            return Err(bad(format!("a `<camera>` without a `label` (line {line}); its image cannot be found")));
        };
        let what = format!("camera `{label}`");
        let id = cam.attribute("id").ok_or_else(|| bad(format!("{what} has no `id` (line {line})")))?;
        if let Some((_, first)) = seen.iter().find(|(l, _)| *l == label) {
            return Err(bad(format!("{what} is listed twice (cameras {first} and {id}); every image has one pose")));
        }
        if let Some((other, _)) = seen.iter().find(|(_, i)| *i == id) {
            return Err(bad(format!("{what}: the camera id {id} is also camera `{other}`'s")));
        }
        seen.push((label, id));
        let sensor_id =
            cam.attribute("sensor_id").ok_or_else(|| bad(format!("{what} has no `sensor_id` (line {line})")))?;
        let Some((sensor_key, sensor_what, sensor)) = sensors.iter().find(|(i, _, _)| *i == sensor_id) else {
            let known: Vec<&str> = sensors.iter().map(|(i, _, _)| *i).collect();
            return Err(bad(format!(
                "{what} uses the sensor {sensor_id}, which `<sensors>` does not define (sensors: {})",
                if known.is_empty() { "none".to_string() } else { known.join(", ") }
            )));
        };
        if !enabled(cam, &what).map_err(bad)? {
            out.disabled.push(label.to_string());
            continue;
        }
        let Some(transform) = child(cam, "transform", &what).map_err(bad)? else {
            if let Some(master) = cam.attribute("master_id").filter(|m| *m != id) {
                return Err(bad(format!(
                    "{what} is a secondary camera of a multi-camera system (master_id {master}) without a \
                     `<transform>` of its own; its pose (its master's and its sensor's offset) is not read: export \
                     the cameras with every camera's transform, or import the master cameras only"
                )));
            }
            out.unaligned.push(label.to_string());
            continue;
        };
        let chunk_from_camera = camera_transform(path, transform, &what).map_err(bad)?;
        let world_from_chunk = match cam.attribute("component_id") {
            Some(cid) => {
                let Some((_, own)) = components.iter().find(|(i, _)| *i == cid) else {
                    return Err(bad(format!(
                        "{what} belongs to the component {cid}, which `<components>` does not define"
                    )));
                };
                match (own, &chunk_world) {
                    (Some(own), Some(chunk)) if !own.abs_diff_eq(*chunk, 1e-9 * (1.0 + chunk.translation.length())) => {
                        return Err(bad(format!(
                            "{what} belongs to the component {cid}, whose `<transform>` differs from the chunk's: \
                             which one places the camera is not clear; export the cameras again from one \
                             Metashape version"
                        )));
                    }
                    (Some(own), _) => Some(*own),
                    (None, chunk) => *chunk,
                }
            }
            None => chunk_world,
        };
        match &placed {
            None => placed = Some((world_from_chunk.is_some(), label.to_string())),
            Some((first, other)) if *first != world_from_chunk.is_some() => {
                let (with, without) = if *first { (other.as_str(), label) } else { (label, other.as_str()) };
                return Err(bad(format!(
                    "camera `{with}` is placed by its component's (or the chunk's) `<transform>` and camera \
                     `{without}` by none: they stand in different frames; export the cameras of one component"
                )));
            }
            Some(_) => {}
        }
        let pose = match &world_from_chunk {
            Some(w) => world_from_camera(w, &chunk_from_camera),
            None => chunk_from_camera,
        };
        let (intrinsics, distortion) = match calibrated.get(sensor_key) {
            Some(c) => *c,
            None => {
                let c = sensor_camera(path, *sensor, sensor_what).map_err(bad)?;
                calibrated.insert(sensor_key, c);
                c
            }
        };
        let camera = Camera { intrinsics, distortion, world_from_camera: pose, lens: None };
        camera.validate().map_err(|e| bad(format!("{what}: {e}")))?;
        out.cameras.push((label.to_string(), camera));
    }
    if out.cameras.is_empty() {
        let mut why = Vec::new();
        if !out.unaligned.is_empty() {
            why.push(format!("not aligned: {}", out.unaligned.join(", ")));
        }
        if !out.disabled.is_empty() {
            why.push(format!("disabled: {}", out.disabled.join(", ")));
        }
        return Err(bad(if why.is_empty() {
            "`<cameras>` lists no camera".to_string()
        } else {
            format!("no camera is both enabled and aligned ({})", why.join("; "))
        }));
    }
    out.units = placed.is_some_and(|(placed, _)| placed).then_some("m");
    Ok(out)
}
