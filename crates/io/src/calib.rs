//! Camera calibrations from other tools: OpenCV `cv::FileStorage` files (YAML, XML or JSON),
//! COLMAP models (text or binary), Agisoft Metashape camera exports (read only, see
//! [`read_metashape`]) and projection matrices or DLT coefficients (read only, see
//! [`read_projection`]); and writing the first two back.
//!
//! # OpenCV (`cv::FileStorage`: YAML `%YAML:1.0` with `!!opencv-matrix`, XML or JSON)
//! Per camera:
//! - `camera_matrix`: 3 × 3 K (`fx skew cx / 0 fy cy / 0 0 1`), pixel centres at integers
//!   (OpenCV's convention is fluidnerf's: no shift). A principal point outside the image is
//!   warned about (intrinsics of another resolution, as in COLMAP models).
//! - `distortion_coefficients`: 0, 4, 5, 8 (or 12/14 with zero thin-prism/tilt terms) values in
//!   OpenCV's order `k1 k2 p1 p2 [k3 [k4 k5 k6]]` (optional; none means no distortion, with a
//!   warning when the file has a node named like a distortion that is not read: `dist_coeffs`,
//!   `distCoeffs`, `D`, `kc`). A file marking OpenCV's fisheye model (`fisheye_model` not 0,
//!   or a `distortion_model` naming it) is refused: its coefficients are not these.
//! - the pose, world → camera (`x_cam = R x_world + t`): `rvec` (Rodrigues vector, 3 values)
//!   and `tvec` (3), or `R` (3 × 3) and `T` (3). If both are given, `R`/`T` win (warning).
//! - `image_width`, `image_height` (integers).
//!
//! Matrices are `!!opencv-matrix`/`opencv-matrix` nodes (`rows cols dt data`) or plain lists.
//! Key names are matched ignoring letter case, so the files of OpenCV's calibration sample
//! (`Camera_Matrix`, `Distortion_Coefficients`, `image_Width`, `image_Height`, with
//! `Avg_Reprojection_Error`, `Extrinsic_Parameters` (the board's poses) and the like, which are
//! listed once at info level and not used) read as they are; such a file has no camera pose, and
//! the error says so, naming the camera and the nodes it looked for.
//!
//! **Several cameras in one file**: every key carries the suffix `_<name>`
//! (`camera_matrix_cam0`, `distortion_coefficients_cam0`, `rvec_cam0`, `tvec_cam0`,
//! `image_width_cam0`, ...), or each camera is a mapping named after it
//! (`cam0: {camera_matrix: ..., R: ..., T: ..., image_width: ...}`), or the cameras are a list
//! of such mappings (`cameras: [{name: left, camera_matrix: ...}, ...]`; an entry without a
//! `name` is `cam<index>`, counting from 0). A camera's name is the suffix of its
//! `camera_matrix_<name>` (a suffix that two or more other per-camera keys carry, as `R_cam2` and
//! `T_cam2` without `camera_matrix_cam2`, names a camera too, refused for the node it lacks); its other keys may spell the suffix in another letter case
//! (`rvec_Left` beside `camera_matrix_left`) unless two names differ only in letter case. A
//! file with unsuffixed keys holds one camera named
//! after the file stem (`cam3.yml` → `cam3`); a file may not mix unsuffixed and suffixed keys.
//! A folder is read as all its `.yml`, `.yaml`, `.xml` and `.json` files in name order; camera
//! names must be unique. [`write_opencv`] writes unsuffixed keys when it writes a single camera
//! whose name is the file stem, and suffixed keys otherwise, so reading gives back the same
//! names.
//!
//! **XML** (`<opencv_storage>`, the calibration sample's default) reads into the same tree as
//! YAML: an element with `type_id="opencv-matrix"` is a matrix (`rows cols dt data`), elements
//! with children are mappings (sequences when the children are `<_>`), and text is a quoted
//! string, a number or a whitespace-separated list of numbers.
//!
//! **Stereo calibrations** (`cv::stereoCalibrate`): `M1 D1 M2 D2` and `R T` (camera 2 from
//! camera 1, `x₂ = R x₁ + T`) in one file, or as `intrinsics.*` with `extrinsics.*` beside it
//! (read together, given either file or the folder; a folder skips the extrinsics file on its
//! own). The cameras are `cam1` and `cam2`. Camera 1 is the world frame (identity pose) unless
//! the file gives its world → camera pose as `rvec1`/`tvec1` (or `rvec`/`tvec`); camera 2's
//! pose is then `R R₁`, `R t₁ + T`. The image size of camera `i` is `image_width<i>`/
//! `image_height<i>` or `imageSize<i>`, else the shared `image_width`/`image_height` or
//! `imageSize`/`image_size` (`[width, height]`); OpenCV's stereo sample writes none, and the
//! error names the keys looked for. `R1 R2 P1 P2 Q` (rectification) are not used (info line).
//!
//! **Errors** name the file, the camera and the node as the file spells it
//! (``calib.xml: camera `cam2`: `D2` has 3 values; expected 4, 5, 8, 12 or 14``); malformed
//! XML/YAML/JSON, matrices whose `rows × cols` is not their data's length, non-numeric data and
//! wrong sizes are errors, never panics.
//!
//! # COLMAP models (text or binary)
//! `cameras.txt` (`CAMERA_ID MODEL WIDTH HEIGHT PARAMS...` with models `SIMPLE_PINHOLE f cx cy`,
//! `PINHOLE fx fy cx cy`, `SIMPLE_RADIAL f cx cy k`, `RADIAL f cx cy k1 k2`,
//! `OPENCV fx fy cx cy k1 k2 p1 p2`, `FULL_OPENCV fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6`) and
//! `images.txt` (`IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then a line of 2D points),
//! where the quaternion and translation map world to camera. COLMAP puts pixel centres at
//! `+0.5` (the image's top-left corner is `(0, 0)`), so `cx_core = cx − 0.5` (same for cy).
//! The radial models are OpenCV's with the missing coefficients zero. The binary files
//! `cameras.bin` and `images.bin` hold the same records, little-endian, as COLMAP's
//! `WriteCamerasBinary`/`WriteImagesBinary` write them (model ids instead of names, 2D points
//! skipped); when both kinds are present the binary files are read.
//!
//! # Agisoft Metashape camera exports ("Agisoft XML")
//! Frame sensors, poses through the chunk's (or component's) transform, principal points from
//! the image centre at `+0.5` pixel centres, and Metashape's `P1`/`P2` swapped into OpenCV's
//! order: see [`read_metashape`]'s module, `metashape`, for every conversion.

use std::path::{Path, PathBuf};

use fluidnerf_core::glam::{DAffine3, DMat3, DQuat, DVec3};
use fluidnerf_core::{num, Camera, Distortion, Intrinsics};
use serde_json::{json, Map, Value};

use crate::{atomic_write, IoError};

mod metashape;
mod projection;
pub use metashape::{read_metashape, MetashapeCameras};
pub use projection::{
    camera_from_projection, flip_v, projection_of, read_projection, ProjectionCamera, ProjectionForm,
};

/// Rotation matrix of a Rodrigues (axis × angle) vector, as `cv::Rodrigues`:
/// `R = cos θ I + (1 − cos θ) k kᵀ + sin θ [k]×` with `θ = |r|`, `k = r / θ`.
pub fn rodrigues_to_matrix(r: DVec3) -> DMat3 {
    let theta = r.length();
    if theta < 1e-300 {
        return DMat3::IDENTITY;
    }
    let k = r / theta;
    let (s, c) = theta.sin_cos();
    let kx = DMat3::from_cols(DVec3::new(0.0, k.z, -k.y), DVec3::new(-k.z, 0.0, k.x), DVec3::new(k.y, -k.x, 0.0));
    let kkt = DMat3::from_cols(k * k.x, k * k.y, k * k.z);
    DMat3::IDENTITY * c + kkt * (1.0 - c) + kx * s
}

/// Rodrigues vector of a rotation matrix (the inverse of [`rodrigues_to_matrix`]; angle in
/// `[0, π]`). Goes through a unit quaternion, which stays accurate near 0 and π.
pub fn matrix_to_rodrigues(m: DMat3) -> DVec3 {
    let mut q = DQuat::from_mat3(&m).normalize();
    if q.w < 0.0 {
        q = -q;
    }
    let v = DVec3::new(q.x, q.y, q.z);
    let s = v.length();
    if s < 1e-300 {
        return 2.0 * v;
    }
    v * (2.0 * s.atan2(q.w) / s)
}

/// A pose from world → camera rotation and translation (`x_cam = R x_world + t`).
pub fn world_from_camera_of(camera_from_world_rotation: DMat3, t: DVec3) -> DAffine3 {
    DAffine3::from_mat3_translation(camera_from_world_rotation, t).inverse()
}

/// YAML (as `yaml-rust2` parses it) → JSON values, so both formats share one reader.
fn yaml_to_json(y: &yaml_rust2::Yaml) -> Value {
    use yaml_rust2::Yaml;
    match y {
        Yaml::Real(s) => {
            s.parse::<f64>().ok().and_then(serde_json::Number::from_f64).map_or(Value::Null, Value::Number)
        }
        Yaml::Integer(i) => json!(i),
        Yaml::String(s) => Value::String(s.clone()),
        Yaml::Boolean(b) => Value::Bool(*b),
        Yaml::Array(a) => Value::Array(a.iter().map(yaml_to_json).collect()),
        Yaml::Hash(h) => {
            let mut m = Map::new();
            for (k, v) in h {
                let key = match k {
                    Yaml::String(s) => s.clone(),
                    Yaml::Integer(i) => i.to_string(),
                    _ => continue,
                };
                m.insert(key, yaml_to_json(v));
            }
            Value::Object(m)
        }
        _ => Value::Null,
    }
}

/// At most this many YAML nodes may come from aliases (`*name`, each a copy of the node its
/// anchor `&name` marks). OpenCV writes no aliases; a hand-written file may share a small node
/// or two, while nested aliases grow exponentially (a "billion laughs" document) and would
/// exhaust memory when expanded.
const MAX_ALIAS_NODES: u64 = 100_000;

/// Counts the nodes a YAML document's aliases expand to, without expanding them.
#[derive(Default)]
struct AliasCount {
    /// Expanded node count of each anchored node, by anchor id.
    anchors: std::collections::HashMap<usize, u64>,
    /// Open collections: (anchor id, expanded nodes so far).
    open: Vec<(usize, u64)>,
    /// Nodes that aliases add.
    from_aliases: u64,
}

impl AliasCount {
    fn node(&mut self, anchor: usize, size: u64) {
        if anchor > 0 {
            self.anchors.insert(anchor, size);
        }
        if let Some((_, n)) = self.open.last_mut() {
            *n = n.saturating_add(size);
        }
    }
}

impl yaml_rust2::parser::EventReceiver for AliasCount {
    fn on_event(&mut self, ev: yaml_rust2::Event) {
        use yaml_rust2::Event;
        match ev {
            Event::Scalar(_, _, anchor, _) => self.node(anchor, 1),
            Event::SequenceStart(anchor, _) | Event::MappingStart(anchor, _) => self.open.push((anchor, 1)),
            Event::SequenceEnd | Event::MappingEnd => {
                if let Some((anchor, size)) = self.open.pop() {
                    self.node(anchor, size);
                }
            }
            Event::Alias(id) => {
                let size = self.anchors.get(&id).copied().unwrap_or(1);
                self.from_aliases = self.from_aliases.saturating_add(size);
                self.node(0, size);
            }
            _ => {}
        }
    }
}

/// Parses YAML `body` of the file `path`, refusing a document whose aliases would expand to
/// more than [`MAX_ALIAS_NODES`] nodes before expanding anything.
fn load_yaml(path: &Path, body: &str) -> Result<Vec<yaml_rust2::Yaml>, IoError> {
    let malformed = |e: yaml_rust2::ScanError| IoError::invalid(path, format!("malformed YAML: {e}"));
    let mut count = AliasCount::default();
    yaml_rust2::parser::Parser::new_from_str(body).load(&mut count, true).map_err(malformed)?;
    if count.from_aliases > MAX_ALIAS_NODES {
        return Err(IoError::invalid(
            path,
            format!(
                "its YAML aliases (`*name`) expand to {}{} nodes, more than the {MAX_ALIAS_NODES} allowed; an OpenCV \
                 calibration needs none: write the nodes out instead of nesting aliases",
                if count.from_aliases == u64::MAX { "over " } else { "" },
                count.from_aliases
            ),
        ));
    }
    yaml_rust2::YamlLoader::load_from_str(body).map_err(malformed)
}

/// JSON text as a value, refusing an object that gives a key twice: serde_json keeps the last
/// of them without a word, where the YAML and XML readers refuse a node given twice.
fn json_without_duplicates(text: &str) -> Result<Value, serde_json::Error> {
    use serde::de::{DeserializeSeed, Deserializer, Error, MapAccess, SeqAccess, Visitor};

    struct Strict;
    impl<'de> DeserializeSeed<'de> for Strict {
        type Value = Value;
        fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
            d.deserialize_any(Strict)
        }
    }
    impl<'de> Visitor<'de> for Strict {
        type Value = Value;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a JSON value")
        }
        fn visit_bool<E: Error>(self, v: bool) -> Result<Value, E> {
            Ok(Value::Bool(v))
        }
        fn visit_i64<E: Error>(self, v: i64) -> Result<Value, E> {
            Ok(Value::from(v))
        }
        fn visit_u64<E: Error>(self, v: u64) -> Result<Value, E> {
            Ok(Value::from(v))
        }
        fn visit_f64<E: Error>(self, v: f64) -> Result<Value, E> {
            Ok(serde_json::Number::from_f64(v).map_or(Value::Null, Value::Number))
        }
        fn visit_str<E: Error>(self, v: &str) -> Result<Value, E> {
            Ok(Value::String(v.to_string()))
        }
        fn visit_unit<E: Error>(self) -> Result<Value, E> {
            Ok(Value::Null)
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
            let mut out = Vec::new();
            while let Some(v) = seq.next_element_seed(Strict)? {
                out.push(v);
            }
            Ok(Value::Array(out))
        }
        fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
            let mut out = Map::new();
            while let Some(key) = map.next_key::<String>()? {
                if out.contains_key(&key) {
                    return Err(A::Error::custom(format!("`{key}` is given twice in one object")));
                }
                let v = map.next_value_seed(Strict)?;
                out.insert(key, v);
            }
            Ok(Value::Object(out))
        }
    }
    let mut de = serde_json::Deserializer::from_str(text);
    let value = Strict.deserialize(&mut de)?;
    de.end()?;
    Ok(value)
}

/// The top-level nodes of a `cv::FileStorage` file, and its text.
fn parse_storage(path: &Path) -> Result<(Map<String, Value>, String), IoError> {
    let text = crate::read_input_text(path, "calibration file")?;
    let is_json =
        path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) || text.trim_start().starts_with('{');
    let trimmed = text.trim_start_matches('\u{feff}').trim_start();
    let is_xml = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("xml"))
        || trimmed.starts_with("<?xml")
        || trimmed.starts_with("<opencv_storage");
    let value = if is_xml {
        xml_storage(path, &text)?
    } else if is_json {
        json_without_duplicates(&text).map_err(|error| IoError::json(path, &text, &error))?
    } else {
        // `%YAML:1.0` is OpenCV's spelling, not valid YAML; drop directive lines.
        let body: String = text.lines().filter(|l| !l.starts_with('%')).map(|l| format!("{l}\n")).collect();
        let docs = load_yaml(path, &body)?;
        docs.first().map(yaml_to_json).unwrap_or(Value::Null)
    };
    match value {
        Value::Object(m) => Ok((m, text)),
        _ => Err(IoError::invalid(path, "expected a mapping of named nodes at the top level")),
    }
}

/// An OpenCV FileStorage XML document as the tree its YAML form parses to: elements with
/// element children are mappings (sequences when every child is `<_>`), an `opencv-matrix` is a
/// mapping of `rows`, `cols`, `dt` and `data`, and text is a quoted string, one number, a list
/// of numbers (whitespace-separated) or a string.
fn xml_storage(path: &Path, text: &str) -> Result<Value, IoError> {
    // The XML parser recurses per element: refuse absurd nesting before it sees it.
    if xml_nesting(text) > 64 {
        return Err(IoError::invalid(path, "elements nested more than 64 deep; not a calibration file"));
    }
    let doc = roxmltree::Document::parse(text).map_err(|e| IoError::invalid(path, format!("malformed XML: {e}")))?;
    let root = doc.root_element();
    if root.tag_name().name() != "opencv_storage" {
        return Err(IoError::invalid(
            path,
            format!(
                "the root element is `<{}>`; OpenCV FileStorage XML has `<opencv_storage>`",
                root.tag_name().name()
            ),
        ));
    }
    if !root.children().any(|n| n.is_element()) {
        // An empty storage is an empty mapping, not an empty string.
        return Ok(Value::Object(Map::new()));
    }
    xml_node(path, root, 0)
}

/// The deepest element nesting of `text`, from its tags alone (comments and declarations
/// skipped; enough to bound the parser's recursion).
fn xml_nesting(text: &str) -> usize {
    let b = text.as_bytes();
    let (mut depth, mut deepest) = (0usize, 0usize);
    let mut i = 0;
    while let Some(off) = b[i..].iter().position(|&c| c == b'<') {
        let start = i + off;
        let end = b[start..].iter().position(|&c| c == b'>').map_or(b.len(), |e| start + e);
        match b.get(start + 1) {
            Some(b'/') => depth = depth.saturating_sub(1),
            Some(b'?' | b'!') => {}
            _ if end > start && b[end - 1] == b'/' => {}
            _ => {
                depth += 1;
                deepest = deepest.max(depth);
            }
        }
        i = end.min(b.len() - 1) + 1;
        if i >= b.len() {
            break;
        }
    }
    deepest
}

fn xml_node(path: &Path, node: roxmltree::Node<'_, '_>, depth: usize) -> Result<Value, IoError> {
    // Calibrations nest a few levels (camera › matrix › data); far deeper is not a calibration.
    if depth > 32 {
        return Err(IoError::invalid(path, format!("elements nested more than 32 deep (line {})", doc_line(node))));
    }
    let children: Vec<roxmltree::Node<'_, '_>> = node.children().filter(roxmltree::Node::is_element).collect();
    if children.is_empty() {
        let text: String = node.children().filter(|n| n.is_text()).filter_map(|n| n.text()).collect();
        return Ok(xml_text(&text));
    }
    if children.iter().all(|c| c.tag_name().name() == "_") {
        return children
            .into_iter()
            .map(|c| xml_node(path, c, depth + 1))
            .collect::<Result<Vec<_>, _>>()
            .map(Value::Array);
    }
    let mut map = Map::new();
    if let Some(t) = node.attribute("type_id") {
        map.insert("type_id".into(), Value::String(t.into()));
    }
    for c in children {
        let name = c.tag_name().name().to_string();
        if map.contains_key(&name) {
            return Err(IoError::invalid(
                path,
                format!("`<{name}>` appears twice in `<{}>` (line {})", node.tag_name().name(), doc_line(c)),
            ));
        }
        map.insert(name, xml_node(path, c, depth + 1)?);
    }
    Ok(Value::Object(map))
}

fn doc_line(node: roxmltree::Node<'_, '_>) -> u32 {
    node.document().text_pos_at(node.range().start).row
}

fn xml_text(text: &str) -> Value {
    let t = text.trim();
    if t.len() >= 2 && t.starts_with('"') && t.ends_with('"') {
        return Value::String(t[1..t.len() - 1].to_string());
    }
    let number = |s: &str| -> Option<Value> {
        if let Ok(i) = s.parse::<i64>() {
            return Some(Value::from(i));
        }
        s.parse::<f64>().ok().and_then(serde_json::Number::from_f64).map(Value::Number)
    };
    let tokens: Vec<&str> = t.split_whitespace().collect();
    match tokens.as_slice() {
        [] => Value::String(String::new()),
        [one] => number(one).unwrap_or_else(|| Value::String(t.to_string())),
        many => many
            .iter()
            .map(|s| number(s))
            .collect::<Option<Vec<_>>>()
            .map_or_else(|| Value::String(t.to_string()), Value::Array),
    }
}

/// A matrix node (`opencv-matrix` with rows/cols/data, or a plain, possibly nested, list) as
/// its row-major values. `what` names the node in messages (``camera `left`: `R` ``).
fn matrix(path: &Path, what: &str, v: &Value) -> Result<Vec<f64>, IoError> {
    let bad = |why: &str| IoError::invalid(path, format!("{what}: {why}"));
    let numbers = |list: &Value| -> Result<Vec<f64>, IoError> {
        let mut out = Vec::new();
        let mut stack = vec![list];
        while let Some(v) = stack.pop() {
            match v {
                Value::Array(a) => stack.extend(a.iter().rev()),
                Value::Number(n) => out.push(n.as_f64().ok_or_else(|| bad("not a number"))?),
                _ => return Err(bad("matrix data must be numbers (NaN and infinities are not allowed)")),
            }
        }
        Ok(out)
    };
    match v {
        Value::Object(m) => {
            let data = numbers(m.get("data").ok_or_else(|| bad("matrix without `data`"))?)?;
            let dim = |k: &str| -> Result<Option<u64>, IoError> {
                match m.get(k) {
                    None => Ok(None),
                    Some(v) => {
                        v.as_u64().map(Some).ok_or_else(|| bad(&format!("`{k}` must be a non-negative integer")))
                    }
                }
            };
            if let (Some(r), Some(c)) = (dim("rows")?, dim("cols")?) {
                if r.checked_mul(c) != Some(data.len() as u64) {
                    return Err(bad(&format!("rows × cols = {r} × {c} but {} values", data.len())));
                }
            }
            Ok(data)
        }
        Value::Array(_) => numbers(v),
        Value::Number(_) => numbers(&Value::Array(vec![v.clone()])),
        _ => Err(bad("expected a matrix")),
    }
}

/// Where the nodes of one camera come from, looked up by their keys in [`OPENCV_KEYS`].
struct CameraNodes<'a> {
    /// The node, if the file has it.
    get: &'a dyn Fn(&str) -> Option<Value>,
    /// The node's name as the file spells it (`Camera_Matrix`, `camera_matrix_left`, `M1`).
    label: &'a dyn Fn(&str) -> String,
    /// The file the node is in (a stereo pair's `R` and `T` may be in a second file).
    file: &'a dyn Fn(&str) -> PathBuf,
}

/// The counts of distortion coefficients OpenCV writes.
const DISTORTION_COUNTS: [usize; 6] = [0, 4, 5, 8, 12, 14];

fn camera_from_nodes(name: &str, nodes: &CameraNodes<'_>) -> Result<Camera, IoError> {
    let what = |key: &str| format!("camera `{name}`: `{}`", (nodes.label)(key));
    let bad = |key: &str, why: String| IoError::invalid((nodes.file)(key), format!("{}: {why}", what(key)));
    // "`D2` has 3 values; ...", "`image_width` must be ...".
    let says = |key: &str, why: String| IoError::invalid((nodes.file)(key), format!("{} {why}", what(key)));
    let need = |key: &str| {
        (nodes.get)(key).ok_or_else(|| {
            IoError::invalid((nodes.file)(key), format!("camera `{name}`: missing the node `{}`", (nodes.label)(key)))
        })
    };
    let read = |key: &str| -> Result<Vec<f64>, IoError> { matrix(&(nodes.file)(key), &what(key), &need(key)?) };
    let sized = |key: &str, n: usize, shape: &str| -> Result<Vec<f64>, IoError> {
        let v = read(key)?;
        if v.len() != n {
            return Err(says(key, format!("has {} values; expected {n} ({shape})", v.len())));
        }
        Ok(v)
    };
    let k = sized("camera_matrix", 9, "3 × 3")?;
    if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        return Err(bad("camera_matrix", "the last rows must be [0 fy cy; 0 0 1]".into()));
    }
    let size = |key: &str| -> Result<u32, IoError> {
        need(key)?
            .as_u64()
            .and_then(|v| u32::try_from(v).ok())
            .filter(|&v| v > 0)
            .ok_or_else(|| says(key, "must be a positive integer".into()))
    };
    let intrinsics = Intrinsics {
        width: size("image_width")?,
        height: size("image_height")?,
        fx: k[0],
        fy: k[4],
        cx: k[2],
        cy: k[5],
        skew: k[1],
    };
    intrinsics.validate().map_err(|e| bad("camera_matrix", e.to_string()))?;
    if let Some(why) = principal_point_outside(&intrinsics) {
        let file = (nodes.file)("camera_matrix");
        log::warn!("{}: camera `{name}`: `{}`: {why}", file.display(), (nodes.label)("camera_matrix"));
    }
    let distortion = match (nodes.get)("distortion_coefficients") {
        None => Distortion::default(),
        Some(_) => {
            let key = "distortion_coefficients";
            let c = read(key)?;
            if !DISTORTION_COUNTS.contains(&c.len()) {
                return Err(says(key, format!("has {} values; expected 4, 5, 8, 12 or 14", c.len())));
            }
            Distortion::from_opencv(&c).map_err(|e| bad(key, e.to_string()))?
        }
    };
    let vec3 = |key: &str| -> Result<DVec3, IoError> {
        let v = sized(key, 3, "a 3-vector")?;
        Ok(DVec3::new(v[0], v[1], v[2]))
    };
    let (rotation, translation, pose_key) = if (nodes.get)("R").is_some() {
        // A `tvec` beside `T` is the second pose as much as an `rvec` beside `R`.
        let ignored: Vec<String> =
            ["rvec", "tvec"].into_iter().filter(|k| (nodes.get)(k).is_some()).map(|k| (nodes.label)(k)).collect();
        if !ignored.is_empty() {
            log::warn!(
                "{}: camera {name}: both {}/{} and {} given; using R/T",
                (nodes.file)("R").display(),
                (nodes.label)("R"),
                (nodes.label)("T"),
                ignored.join("/")
            );
        }
        let r = sized("R", 9, "3 × 3")?;
        (DMat3::from_cols_array(&[r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8]]), vec3("T")?, "R")
    } else if (nodes.get)("rvec").is_some() {
        (rodrigues_to_matrix(vec3("rvec")?), vec3("tvec")?, "rvec")
    } else {
        let board = if (nodes.get)("Extrinsic_Parameters").is_some() {
            " (its `Extrinsic_Parameters` are the calibration board's poses, one per view, not the camera's)"
        } else {
            ""
        };
        return Err(IoError::invalid(
            (nodes.file)("camera_matrix"),
            format!(
                "camera `{name}`: no pose: expected the nodes `{}` and `{}` or `{}` and `{}` (world to \
                 camera); an intrinsics-only calibration (as OpenCV's calibration sample writes) needs a pose \
                 from a separate extrinsic calibration{board}",
                (nodes.label)("rvec"),
                (nodes.label)("tvec"),
                (nodes.label)("R"),
                (nodes.label)("T"),
            ),
        ));
    };
    // A rotation vector whose length overflows gives no rotation, which the camera's check would
    // call a translation that is not finite (the values read are finite).
    if !rotation.is_finite() {
        return Err(bad(
            pose_key,
            "does not give a rotation: the rotation vector is too long for its length to be finite".into(),
        ));
    }
    // A matrix written with few digits is a rotation only up to their rounding, which the
    // camera's check would refuse: the nearest rotation is taken, and said.
    let rotation = match fluidnerf_core::camera::rounded_rotation(rotation) {
        Some((nearest, error)) => {
            log::warn!(
                "{}: camera {name}: {} is a rotation only to within {error:.1e} (written with few digits?); the \
                 nearest rotation is used",
                (nodes.file)(pose_key).display(),
                (nodes.label)(pose_key)
            );
            nearest
        }
        None => rotation,
    };
    // The pose inverts the matrix read: a singular one has no inverse, and the NaN it gives
    // would be blamed on the translation.
    let world_from_camera = world_from_camera_of(rotation, translation);
    if !world_from_camera.is_finite() {
        return Err(says(
            pose_key,
            format!("is singular (determinant {}), not a rotation", num(rotation.determinant())),
        ));
    }
    let camera = Camera { intrinsics, distortion, world_from_camera, lens: None };
    // The intrinsics passed above, so what is left to fail is the pose.
    camera.validate().map_err(|e| bad(pose_key, e.to_string()))?;
    Ok(camera)
}

/// Why the principal point of `k` looks wrong: it lies outside the image, as it does with
/// intrinsics calibrated at another resolution (binned, cropped or the full sensor) than the
/// image size given.
pub fn principal_point_outside(k: &Intrinsics) -> Option<String> {
    // Pixel centres at integers: the image spans -½ to n - ½.
    let inside = |c: f64, n: u32| (-0.5..=f64::from(n) - 0.5).contains(&c);
    (!inside(k.cx, k.width) || !inside(k.cy, k.height)).then(|| {
        format!(
            "the principal point (cx, cy) = ({}, {}) lies outside the {}x{} image: are the intrinsics those of \
             another resolution (binned, cropped or the full sensor)?",
            num(k.cx),
            num(k.cy),
            k.width,
            k.height
        )
    })
}

/// The per-camera keys (suffixed `_<name>` in multi-camera files), longest first so that
/// `rvec` is not taken for `R`.
const OPENCV_KEYS: [&str; 8] =
    ["distortion_coefficients", "camera_matrix", "image_height", "image_width", "rvec", "tvec", "R", "T"];

/// The map with every key that starts with a per-camera key in another letter case
/// (`Camera_Matrix`, `image_Width`, as OpenCV's calibration sample writes them) renamed to the
/// spelling of [`OPENCV_KEYS`], its `_<name>` suffix kept.
fn canonical_keys(nodes: &Map<String, Value>) -> Map<String, Value> {
    nodes.iter().map(|(key, value)| (canonical_key(key), value.clone())).collect()
}

/// `key` with a leading per-camera key spelled as in [`OPENCV_KEYS`] (see [`canonical_keys`]).
fn canonical_key(key: &str) -> String {
    OPENCV_KEYS
        .iter()
        .find(|base| {
            key.len() >= base.len()
                && key.is_char_boundary(base.len())
                && key[..base.len()].eq_ignore_ascii_case(base)
                && (key.len() == base.len() || key[base.len()..].starts_with('_'))
        })
        .map_or_else(|| key.to_string(), |base| format!("{base}{}", &key[base.len()..]))
}

/// `key` as `nodes` spells it (keys match ignoring letter case), or `key` when it is absent.
fn spelled(nodes: &Map<String, Value>, key: &str) -> String {
    nodes.keys().find(|k| k.eq_ignore_ascii_case(key)).cloned().unwrap_or_else(|| key.to_string())
}

/// Of a file's `(node, node without its camera suffix)` pairs, the nodes named like a camera's
/// distortion under a name the reader does not know (`dist_coeffs`, `distCoeffs`, `D`, the
/// calibration toolbox's `kc`).
fn distortion_lookalikes<'a>(nodes: impl Iterator<Item = (&'a str, &'a str)>) -> Vec<&'a str> {
    nodes
        .filter(|(_, base)| {
            let b = base.to_ascii_lowercase().replace('_', "");
            (b.starts_with("dist")
                && !b.starts_with("distance")
                && b != "distortionmodel"
                && b != "distortioncoefficients")
                || b == "d"
                || b == "kc"
        })
        .map(|(node, _)| node)
        .collect()
}

/// Warns that camera `name`, read without distortion (it has no node `wanted`, its
/// `distortion_coefficients`), sits beside `lookalikes` ([`distortion_lookalikes`]): its
/// distortion is most likely there, unread.
fn warn_unread_distortion(path: &Path, name: &str, wanted: &str, lookalikes: &[&str]) {
    if lookalikes.is_empty() {
        return;
    }
    log::warn!(
        "{}: camera `{name}` has no `{wanted}` node and is read without distortion, but the file has {}, which \
         is not read: if that is the camera's distortion (k1 k2 p1 p2 [k3 ...]), rename it `{wanted}`",
        path.display(),
        lookalikes.iter().map(|n| format!("`{n}`")).collect::<Vec<_>>().join(", ")
    );
}

/// A camera whose nodes are one mapping (a whole file, a named mapping or a list entry).
fn camera_from_map(path: &Path, name: &str, raw: &Map<String, Value>) -> Result<Camera, IoError> {
    let nodes = canonical_keys(raw);
    if !nodes.contains_key("distortion_coefficients") {
        let lookalikes = distortion_lookalikes(raw.keys().map(|k| (k.as_str(), k.as_str())));
        warn_unread_distortion(path, name, "distortion_coefficients", &lookalikes);
    }
    camera_from_nodes(
        name,
        &CameraNodes { get: &|k| nodes.get(k).cloned(), label: &|k| spelled(raw, k), file: &|_| path.to_path_buf() },
    )
}

/// The cameras of a list of mappings (`cameras: [{name: left, camera_matrix: ...}, ...]`),
/// named by their `name` node or `cam<index>` (from 0); `None` when `value` is no such list.
fn camera_list(path: &Path, key: &str, value: &Value) -> Result<Option<Vec<(String, Camera)>>, IoError> {
    let Value::Array(items) = value else { return Ok(None) };
    let is_camera = |v: &Value| v.as_object().is_some_and(|m| canonical_keys(m).contains_key("camera_matrix"));
    if !items.iter().any(is_camera) {
        return Ok(None);
    }
    let mut out: Vec<(String, Camera)> = Vec::with_capacity(items.len());
    for (i, item) in items.iter().enumerate() {
        let Some(m) = item.as_object().filter(|_| is_camera(item)) else {
            return Err(IoError::invalid(
                path,
                format!("`{key}[{i}]`: not a camera (expected a mapping with a `camera_matrix`)"),
            ));
        };
        let name = match node_ci(m, "name") {
            None => format!("cam{i}"),
            Some(Value::String(s)) if !s.trim().is_empty() => s.trim().to_string(),
            Some(Value::Number(n)) => n.to_string(),
            Some(Value::String(_)) => {
                return Err(IoError::invalid(
                    path,
                    format!("`{key}[{i}]`: `name` is empty; name the camera or leave the key out"),
                ))
            }
            Some(other) => {
                return Err(IoError::invalid(path, format!("`{key}[{i}]`: `name` must be a string, got {other}")))
            }
        };
        if out.iter().any(|(n, _)| *n == name) {
            return Err(IoError::invalid(path, format!("`{key}[{i}]`: camera name `{name}` appears twice")));
        }
        let camera = camera_from_map(path, &name, m)?;
        out.push((name, camera));
    }
    Ok(Some(out))
}

/// Refuses a file that marks its distortion as OpenCV's fisheye model (`cv::fisheye`): a node
/// `fisheye_model` (per camera `fisheye_model_<name>`) that is not 0 or false, as OpenCV's
/// calibration sample writes, or a `distortion_model` naming a fisheye (ROS: `equidistant`), at the top or in a
/// camera's mapping or list entry. Its four coefficients are the equidistant model's θ terms,
/// and read as k1 k2 p1 p2 they would make a wrong camera without a word.
fn refuse_fisheye(path: &Path, nodes: &Map<String, Value>) -> Result<(), IoError> {
    fn marked(nodes: &Map<String, Value>) -> Option<String> {
        nodes.iter().find_map(|(key, value)| {
            let k = key.to_ascii_lowercase().replace('_', "");
            let fisheye = match value {
                _ if k.starts_with("fisheyemodel") => match value {
                    Value::Bool(b) => *b,
                    Value::Number(n) => n.as_f64() != Some(0.0),
                    Value::String(t) => !matches!(t.trim(), "0" | "false" | ""),
                    _ => false,
                },
                Value::String(t) if k.starts_with("distortionmodel") => {
                    let t = t.to_ascii_lowercase();
                    ["fisheye", "equidistant", "kannala"].iter().any(|m| t.contains(m))
                }
                Value::Object(m) => return marked(m),
                Value::Array(list) => return list.iter().filter_map(Value::as_object).find_map(marked),
                _ => false,
            };
            fisheye.then(|| format!("`{key}: {value}`"))
        })
    }
    match marked(nodes) {
        None => Ok(()),
        Some(node) => Err(IoError::invalid(
            path,
            format!(
                "{node} marks a camera of OpenCV's fisheye model (cv::fisheye), which fluidnerf does not read: its \
                 coefficients are the equidistant model's k1..k4 of the angle θ, not the standard model's k1 k2 p1 \
                 p2. Calibrate with the standard or rational model (cv::calibrateCamera), or undistort the images \
                 with cv::fisheye and import them with the new camera matrix and no distortion"
            ),
        )),
    }
}

fn read_opencv_file(path: &Path) -> Result<Vec<(String, Camera)>, IoError> {
    let (raw_nodes, text) = parse_storage(path)?;
    refuse_fisheye(path, &raw_nodes)?;
    if let Some(cams) = read_stereo(path, &raw_nodes, None)? {
        return Ok(cams);
    }
    let nodes = canonical_keys(&raw_nodes);
    let mut named: Vec<String> = nodes
        .keys()
        .filter_map(|k| k.strip_prefix("camera_matrix_"))
        .filter(|s| !s.is_empty())
        .map(str::to_string)
        .collect();
    let single = nodes.contains_key("camera_matrix");
    if single && !named.is_empty() {
        return Err(IoError::invalid(
            path,
            "mixes an unsuffixed `camera_matrix` with per-camera `camera_matrix_<name>` keys",
        ));
    }
    if !named.is_empty() {
        // A camera whose other nodes are there without its `camera_matrix_<name>` is a camera of
        // the file all the same: it gets the error for the node it lacks, rather than being left
        // out. Two of its nodes make it one; a lone `T_world` may be something else.
        let mut others: Vec<(String, usize)> = Vec::new();
        for key in nodes.keys() {
            let suffix = OPENCV_KEYS
                .iter()
                .filter(|base| **base != "camera_matrix")
                .find_map(|base| key.strip_prefix(base).and_then(|rest| rest.strip_prefix('_')));
            if let Some(n) = suffix.filter(|n| !n.is_empty()) {
                if named.iter().any(|m| m.eq_ignore_ascii_case(n)) {
                    continue;
                }
                match others.iter_mut().find(|(m, _)| m.eq_ignore_ascii_case(n)) {
                    Some((_, count)) => *count += 1,
                    None => others.push((n.to_string(), 1)),
                }
            }
        }
        named.extend(others.into_iter().filter(|(_, count)| *count >= 2).map(|(n, _)| n));
    }
    if !single && named.is_empty() {
        if let Some(intrinsics) = stereo_intrinsics_of(path, &raw_nodes) {
            let (intrinsic_nodes, _) = parse_storage(&intrinsics)?;
            if let Some(cams) = read_stereo(&intrinsics, &intrinsic_nodes, Some(path))? {
                return Ok(cams);
            }
        }
    }
    // One mapping per camera (`cam0: {camera_matrix: ..., R: ..., T: ...}`), or lists of them.
    let grouped = !single && named.is_empty();
    let nested: Vec<(&String, &Map<String, Value>)> = if grouped {
        let mappings: Vec<(&String, &Map<String, Value>)> =
            raw_nodes.iter().filter_map(|(k, v)| v.as_object().map(|m| (k, m))).collect();
        if mappings.iter().any(|(_, m)| canonical_keys(m).contains_key("camera_matrix")) {
            // Beside cameras, a mapping with some of a camera's nodes is one too (and its
            // missing node is named).
            mappings
                .into_iter()
                .filter(|(_, m)| canonical_keys(m).keys().any(|k| OPENCV_KEYS.contains(&k.as_str())))
                .collect()
        } else {
            Vec::new()
        }
    } else {
        Vec::new()
    };
    let mut listed: Vec<(&String, Vec<(String, Camera)>)> = Vec::new();
    if grouped {
        for (k, v) in &raw_nodes {
            if let Some(cams) = camera_list(path, k, v)? {
                listed.push((k, cams));
            }
        }
    }
    let unused: Vec<&String> = raw_nodes
        .keys()
        .filter(|raw| {
            let key = canonical_key(raw);
            let known = OPENCV_KEYS
                .iter()
                .any(|k| key == *k || named.iter().any(|n| key.eq_ignore_ascii_case(&format!("{k}_{n}"))));
            !known && !nested.iter().any(|(n, _)| n == raw) && !listed.iter().any(|(n, _)| n == raw)
        })
        .collect();
    if !unused.is_empty() {
        let list: Vec<&str> = unused.iter().map(|k| k.as_str()).collect();
        log::info!("{}: nodes not used for the cameras: {}", path.display(), list.join(", "));
    }
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    if single {
        let cam = camera_from_map(path, &stem, &raw_nodes)?;
        return Ok(vec![(stem, cam)]);
    }
    if !nested.is_empty() || !listed.is_empty() {
        // Keep the file's order of cameras (the parsed map is sorted by key).
        let mut nested = nested;
        nested.sort_by_key(|(n, _)| {
            text.find(&format!("{n}:"))
                .or_else(|| text.find(&format!("\"{n}\"")))
                .or_else(|| text.find(&format!("<{n}>")))
        });
        let mut out: Vec<(String, Camera)> = Vec::new();
        for (n, m) in nested {
            out.push((n.clone(), camera_from_map(path, n, m)?));
        }
        for (_, cams) in listed {
            out.extend(cams);
        }
        for (i, (n, _)) in out.iter().enumerate() {
            if out[..i].iter().any(|(m, _)| m == n) {
                return Err(IoError::invalid(path, format!("camera name `{n}` appears twice")));
            }
        }
        return Ok(out);
    }
    if named.is_empty() {
        return Err(IoError::invalid(
            path,
            "no camera matrix: expected a `camera_matrix` (or `Camera_Matrix`) node, per-camera \
             `camera_matrix_<name>` nodes, one mapping per camera holding a `camera_matrix`, a list of \
             such mappings, or a stereo calibration's `M1` and `M2`",
        ));
    }
    // Keep the file's order of cameras (the parsed map is sorted by key).
    named.sort_by_key(|n| {
        let key = format!("camera_matrix_{n}");
        text.to_ascii_lowercase()
            .match_indices(&key.to_ascii_lowercase())
            .find(|(i, _)| matches!(text[i + key.len()..].chars().next(), Some('"' | ':' | ' ' | '>')))
            .map(|(i, _)| i)
    });
    named
        .iter()
        .map(|n| {
            if suffixed_node(&nodes, "distortion_coefficients", n, &named).is_none() {
                let suffix = format!("_{}", n.to_ascii_lowercase());
                let own = raw_nodes.keys().filter_map(|k| {
                    let cut = k.len().checked_sub(suffix.len())?;
                    (k.is_char_boundary(cut) && k[cut..].eq_ignore_ascii_case(&suffix)).then(|| (k.as_str(), &k[..cut]))
                });
                let wanted = format!("distortion_coefficients_{n}");
                warn_unread_distortion(path, n, &wanted, &distortion_lookalikes(own));
            }
            let camera = camera_from_nodes(
                n,
                &CameraNodes {
                    get: &|k| suffixed_node(&nodes, k, n, &named),
                    label: &|k| spelled(&raw_nodes, &format!("{k}_{n}")),
                    file: &|_| path.to_path_buf(),
                },
            )?;
            Ok((n.clone(), camera))
        })
        .collect()
}

/// Camera `name`'s node `key` (`key_name`) in a multi-camera file: spelled exactly, or else its
/// one spelling in another letter case (`rvec_Left` for the camera of `camera_matrix_left`), as
/// long as none of the other cameras' `names` differs from `name` only in letter case.
fn suffixed_node(nodes: &Map<String, Value>, key: &str, name: &str, names: &[String]) -> Option<Value> {
    let wanted = format!("{key}_{name}");
    if let Some(v) = nodes.get(&wanted) {
        return Some(v.clone());
    }
    if names.iter().any(|m| m != name && m.eq_ignore_ascii_case(name)) {
        return None;
    }
    let mut found = nodes.iter().filter(|(k, _)| k.eq_ignore_ascii_case(&wanted));
    match (found.next(), found.next()) {
        (Some((_, v)), None) => Some(v.clone()),
        _ => None,
    }
}

/// The node `key` of `nodes`, matched ignoring letter case.
fn node_ci(nodes: &Map<String, Value>, key: &str) -> Option<Value> {
    nodes.iter().find(|(k, _)| k.eq_ignore_ascii_case(key)).map(|(_, v)| v.clone())
}

/// The file `stem` with any of the storage extensions beside `path`, other than `path`.
fn sibling(path: &Path, stem: &str) -> Option<PathBuf> {
    let dir = path.parent()?;
    ["yml", "yaml", "xml", "json"].iter().map(|e| dir.join(format!("{stem}.{e}"))).find(|p| p.is_file() && p != path)
}

/// The intrinsics file of a stereo calibration whose extrinsics are `path`: an
/// `intrinsics.*` beside a file that holds `R` and `T` and no camera matrix.
fn stereo_intrinsics_of(path: &Path, nodes: &Map<String, Value>) -> Option<PathBuf> {
    if node_ci(nodes, "R").is_none() || node_ci(nodes, "T").is_none() {
        return None;
    }
    sibling(path, "intrinsics")
}

/// A stereo calibration as `cv::stereoCalibrate` and its samples write it: `M1 D1 M2 D2` with
/// `R T` (camera 2 from camera 1, `x₂ = R x₁ + T`), in one file or as `intrinsics` +
/// `extrinsics` files side by side (`extrinsics` given, or found beside `path`); `R1 R2 P1 P2
/// Q` (rectification) are not used. Camera 1 (`cam1`) is the world frame unless the files give
/// its world → camera pose as `rvec1`/`tvec1` (or `rvec`/`tvec`). `None` when `path` holds no
/// `M1`/`M2`.
fn read_stereo(
    path: &Path,
    nodes: &Map<String, Value>,
    extrinsics: Option<&Path>,
) -> Result<Option<Vec<(String, Camera)>>, IoError> {
    if node_ci(nodes, "M1").is_none() && node_ci(nodes, "M2").is_none() {
        return Ok(None);
    }
    let mut all = nodes.clone();
    // The keys that came from the extrinsics file, matched ignoring case.
    let mut from_extrinsics: Vec<String> = Vec::new();
    let mut ext_path: Option<PathBuf> = None;
    if node_ci(&all, "R").is_none() || node_ci(&all, "T").is_none() {
        let Some(ext) = extrinsics.map(Path::to_path_buf).or_else(|| sibling(path, "extrinsics")) else {
            return Err(IoError::invalid(
                path,
                "a stereo calibration (`M1`, `M2`) without `R` and `T`: give them in this file or in an \
                 `extrinsics.yml` (or .yaml, .xml, .json) beside it",
            ));
        };
        let (more, _) = parse_storage(&ext)?;
        for (k, v) in more {
            if node_ci(&all, &k).is_none() {
                from_extrinsics.push(k.to_ascii_lowercase());
                all.insert(k, v);
            }
        }
        ext_path = Some(ext);
    }
    let source = match &ext_path {
        Some(e) => format!("{} with {}", path.display(), e.display()),
        None => path.display().to_string(),
    };
    let file_of = |key: &str| -> PathBuf {
        match &ext_path {
            Some(e) if from_extrinsics.contains(&key.to_ascii_lowercase()) => e.clone(),
            _ => path.to_path_buf(),
        }
    };
    log::info!("{source}: a stereo calibration (R1, R2, P1, P2 and Q, if present, are not used)");

    // The image size of camera `i`: its own nodes first, then the shared ones.
    let image_size = |i: usize| -> Result<(u32, u32, String), IoError> {
        for suffix in [i.to_string(), String::new()] {
            let (w, h) = (format!("image_width{suffix}"), format!("image_height{suffix}"));
            if let (Some(wv), Some(hv)) = (node_ci(&all, &w), node_ci(&all, &h)) {
                let int = |key: &str, v: &Value| {
                    v.as_u64().and_then(|v| u32::try_from(v).ok()).filter(|&v| v > 0).ok_or_else(|| {
                        IoError::invalid(
                            file_of(key),
                            format!("camera `cam{i}`: `{}` must be a positive integer", spelled(&all, key)),
                        )
                    })
                };
                return Ok((int(&w, &wv)?, int(&h, &hv)?, format!("{}/{}", spelled(&all, &w), spelled(&all, &h))));
            }
            for key in [format!("imageSize{suffix}"), format!("image_size{suffix}")] {
                if let Some(v) = node_ci(&all, &key) {
                    let label = spelled(&all, &key);
                    let what = format!("camera `cam{i}`: `{label}`");
                    let wh = matrix(&file_of(&key), &what, &v)?;
                    let ok = |x: f64| x.fract() == 0.0 && x >= 1.0 && x <= f64::from(u32::MAX);
                    if wh.len() != 2 || !ok(wh[0]) || !ok(wh[1]) {
                        return Err(IoError::invalid(
                            file_of(&key),
                            format!("{what}: expected [width, height] as two positive integers, got {wh:?}"),
                        ));
                    }
                    return Ok((wh[0] as u32, wh[1] as u32, label));
                }
            }
        }
        Err(IoError::invalid(
            path,
            format!(
                "camera `cam{i}`: no image size: expected `image_width{i}` and `image_height{i}`, \
                 `imageSize{i}`, `image_width` and `image_height`, or `imageSize` ([width, height]); \
                 the stereo sample writes none, so add it"
            ),
        ))
    };

    // Camera 1's world → camera pose, if given.
    let world_pose = ["rvec1", "rvec"].into_iter().find(|k| node_ci(&all, k).is_some());
    let mut cams: Vec<(String, Camera)> = Vec::new();
    for i in [1usize, 2] {
        let name = format!("cam{i}");
        let (w, h, size_label) = image_size(i)?;
        let (m, d) = (format!("M{i}"), format!("D{i}"));
        let identity = (json!([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]), json!([0.0, 0.0, 0.0]));
        let get = |key: &str| -> Option<Value> {
            match key {
                "camera_matrix" => node_ci(&all, &m),
                "distortion_coefficients" => node_ci(&all, &d),
                "image_width" => Some(json!(w)),
                "image_height" => Some(json!(h)),
                "R" if i == 2 => node_ci(&all, "R"),
                "T" if i == 2 => node_ci(&all, "T"),
                "R" if world_pose.is_none() => Some(identity.0.clone()),
                "T" if world_pose.is_none() => Some(identity.1.clone()),
                "rvec" if i == 1 => world_pose.and_then(|r| node_ci(&all, r)),
                "tvec" if i == 1 => world_pose.and_then(|r| node_ci(&all, &r.replace('r', "t"))),
                _ => None,
            }
        };
        let key_of = |key: &str| -> String {
            match key {
                "camera_matrix" => m.clone(),
                "distortion_coefficients" => d.clone(),
                "image_width" | "image_height" => size_label.clone(),
                "rvec" | "tvec" => world_pose.map_or_else(|| key.to_string(), |r| r.replace('r', &key[..1])),
                other => other.to_string(),
            }
        };
        let camera = camera_from_nodes(
            &name,
            &CameraNodes { get: &get, label: &|k| spelled(&all, &key_of(k)), file: &|k| file_of(&key_of(k)) },
        )?;
        cams.push((name, camera));
    }
    if world_pose.is_some() {
        // cam2's pose was read relative to cam1: world ← cam1 ← cam2.
        let world_from_cam1 = cams[0].1.world_from_camera;
        let cam2 = &mut cams[1].1;
        cam2.world_from_camera = world_from_cam1 * cam2.world_from_camera;
    }
    let used = ["M1", "D1", "M2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q", "rvec1", "tvec1", "rvec", "tvec"];
    let sizes = ["image_width", "image_height", "imageSize", "image_size"];
    let unused: Vec<&String> = all
        .keys()
        .filter(|k| {
            !used.iter().any(|u| k.eq_ignore_ascii_case(u))
                && !sizes.iter().any(|s| {
                    k.len() >= s.len()
                        && k.is_char_boundary(s.len())
                        && k[..s.len()].eq_ignore_ascii_case(s)
                        && ["", "1", "2"].contains(&&k[s.len()..])
                })
        })
        .collect();
    if !unused.is_empty() {
        let list: Vec<&str> = unused.iter().map(|k| k.as_str()).collect();
        log::info!("{source}: nodes not used for the cameras: {}", list.join(", "));
    }
    Ok(Some(cams))
}

/// The calibration files `path` names: itself, or, for a folder (`what` in errors), its files
/// whose extension is one of `extensions` (any letter case) and that `keep` accepts, in name
/// order; a folder without any is refused with `none`.
fn calibration_files(
    path: &Path,
    what: &'static str,
    extensions: &[&str],
    keep: impl Fn(&Path) -> bool,
    none: &str,
) -> Result<Vec<PathBuf>, IoError> {
    if !path.is_dir() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|e| IoError::io(path, what, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .and_then(|e| e.to_str())
                    .is_some_and(|e| extensions.iter().any(|x| x.eq_ignore_ascii_case(e)))
                && keep(p)
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(IoError::invalid(path, none));
    }
    Ok(files)
}

/// Reads OpenCV calibration files: one file (one or several cameras) or a folder of them
/// (see the module docs). Returns `(camera name, camera)` in file order.
pub fn read_opencv(path: &Path) -> Result<Vec<(String, Camera)>, IoError> {
    let files = calibration_files(
        path,
        "calibration folder",
        &["yml", "yaml", "json", "xml"],
        // A stereo calibration's extrinsics are read with its intrinsics.
        |p| !p.file_stem().is_some_and(|s| s.eq_ignore_ascii_case("extrinsics")),
        "no .yml, .yaml, .xml or .json calibration files in this folder",
    )?;
    let mut out: Vec<(String, Camera)> = Vec::new();
    for f in &files {
        for (name, cam) in read_opencv_file(f)? {
            if out.iter().any(|(n, _)| *n == name) {
                return Err(IoError::invalid(f, format!("camera name `{name}` appears twice in {}", path.display())));
            }
            out.push((name, cam));
        }
    }
    Ok(out)
}

fn fmt_f64(v: f64) -> String {
    // serde_json's shortest round-trip form always has a `.` or an exponent, so OpenCV and
    // YAML read it as a real.
    serde_json::to_string(&v).unwrap_or_else(|_| format!("{v:e}"))
}

/// A matrix node to write: key, rows, cols, row-major values.
type MatrixNode = (&'static str, usize, usize, Vec<f64>);

/// Image size and the matrix nodes of one camera, world → camera pose as
/// `rvec`/`tvec`.
fn camera_nodes(cam: &Camera) -> (u32, u32, Vec<MatrixNode>) {
    let k = cam.intrinsics.k_rows();
    let camera_from_world = cam.camera_from_world();
    let t = camera_from_world.translation;
    let r = matrix_to_rodrigues(camera_from_world.matrix3);
    let dist = cam.distortion.to_opencv();
    let nodes = vec![
        ("camera_matrix", 3, 3, k.iter().flatten().copied().collect()),
        ("distortion_coefficients", 1, dist.len(), dist),
        ("rvec", 3, 1, r.to_array().to_vec()),
        ("tvec", 3, 1, t.to_array().to_vec()),
    ];
    (cam.intrinsics.width, cam.intrinsics.height, nodes)
}

/// Writes cameras as an OpenCV `cv::FileStorage` file: YAML for `.yml`/`.yaml`, XML for `.xml`,
/// JSON for `.json` (see the module docs for the key layout). Poses are written as `rvec`/`tvec`
/// (world → camera), distortion as 5 coefficients (8 when k4..k6 are used). The thin lens, if
/// any, is not part of the format and is dropped.
pub fn write_opencv(path: &Path, cameras: &[(String, Camera)]) -> Result<(), IoError> {
    assert!(!cameras.is_empty(), "write_opencv: no cameras");
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let unsuffixed = cameras.len() == 1 && cameras[0].0 == stem;
    for (name, _) in cameras {
        if !unsuffixed && (name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-'))
        {
            return Err(IoError::invalid(path, format!("camera name `{name}` must be letters, digits, `_` or `-`")));
        }
    }
    let key = |k: &str, name: &str| if unsuffixed { k.to_string() } else { format!("{k}_{name}") };
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let text = match ext.as_deref() {
        Some("yml" | "yaml") => {
            let mut s = String::from("%YAML:1.0\n---\n");
            for (name, cam) in cameras {
                let (w, h, nodes) = camera_nodes(cam);
                s += &format!("{}: {w}\n{}: {h}\n", key("image_width", name), key("image_height", name));
                for (k, rows, cols, data) in nodes {
                    let data: Vec<String> = data.into_iter().map(fmt_f64).collect();
                    s += &format!(
                        "{}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {} ]\n",
                        key(k, name),
                        data.join(", ")
                    );
                }
            }
            s
        }
        Some("json") => {
            // Written by hand so the cameras keep their order (a JSON map would sort them).
            let mut entries: Vec<(String, Value)> = Vec::new();
            for (name, cam) in cameras {
                let (w, h, nodes) = camera_nodes(cam);
                entries.push((key("image_width", name), json!(w)));
                entries.push((key("image_height", name), json!(h)));
                for (k, rows, cols, data) in nodes {
                    let node = json!({"type_id": "opencv-matrix", "rows": rows, "cols": cols, "dt": "d", "data": data});
                    entries.push((key(k, name), node));
                }
            }
            let mut parts = Vec::with_capacity(entries.len());
            for (k, v) in entries {
                let v = serde_json::to_string_pretty(&v)
                    .map_err(|error| IoError::Json { path: path.to_path_buf(), error: error.to_string() })?
                    .replace('\n', "\n    ");
                parts.push(format!("    {}: {v}", Value::String(k)));
            }
            format!("{{\n{}\n}}\n", parts.join(",\n"))
        }
        Some("xml") => {
            let mut s = String::from("<?xml version=\"1.0\"?>\n<opencv_storage>\n");
            for (name, cam) in cameras {
                let (w, h, nodes) = camera_nodes(cam);
                let (kw, kh) = (key("image_width", name), key("image_height", name));
                s += &format!("<{kw}>{w}</{kw}>\n<{kh}>{h}</{kh}>\n");
                for (k, rows, cols, data) in nodes {
                    let data: Vec<String> = data.into_iter().map(fmt_f64).collect();
                    let k = key(k, name);
                    s += &format!(
                        "<{k} type_id=\"opencv-matrix\">\n  <rows>{rows}</rows>\n  <cols>{cols}</cols>\n  \
                         <dt>d</dt>\n  <data>\n    {}</data></{k}>\n",
                        data.join(" ")
                    );
                }
            }
            s + "</opencv_storage>\n"
        }
        _ => return Err(IoError::invalid(path, "OpenCV calibration files must end in .yml, .yaml, .xml or .json")),
    };
    atomic_write(path, |w| w.write_all(text.as_bytes()))
}

/// COLMAP's camera models by id (`colmap/src/colmap/sensor/models.h`) with their parameter
/// counts; only the first six are read, the others are named in the error.
const COLMAP_MODELS: [(&str, usize); 12] = [
    ("SIMPLE_PINHOLE", 3),
    ("PINHOLE", 4),
    ("SIMPLE_RADIAL", 4),
    ("RADIAL", 5),
    ("OPENCV", 8),
    ("OPENCV_FISHEYE", 8),
    ("FULL_OPENCV", 12),
    ("FOV", 5),
    ("SIMPLE_RADIAL_FISHEYE", 4),
    ("RADIAL_FISHEYE", 5),
    ("THIN_PRISM_FISHEYE", 12),
    ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
];

/// Intrinsics and distortion of a COLMAP camera (`params` in COLMAP's order, principal point
/// measured from the image corner).
fn colmap_camera(model: &str, width: u32, height: u32, p: &[f64]) -> Result<(Intrinsics, Distortion), String> {
    let expected = match model {
        "SIMPLE_PINHOLE" => 3,
        "PINHOLE" | "SIMPLE_RADIAL" => 4,
        "RADIAL" => 5,
        "OPENCV" => 8,
        "FULL_OPENCV" => 12,
        other => {
            return Err(format!(
                "camera model {other} is not supported (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV)"
            ))
        }
    };
    if p.len() != expected {
        return Err(format!("{model} takes {expected} parameters, got {}", p.len()));
    }
    // Checked for every model here: a radial term is copied as it is, and a NaN one would
    // only show later as an undistortion that does not converge, blamed on the scene.
    if let Some((i, v)) = p.iter().enumerate().find(|(_, v)| !v.is_finite()) {
        return Err(format!("{model} parameter {} of {expected} is {}; parameters must be finite", i + 1, num(*v)));
    }
    let (fx, fy, cx, cy, rest) = match model {
        "SIMPLE_PINHOLE" | "SIMPLE_RADIAL" | "RADIAL" => (p[0], p[0], p[1], p[2], &p[3..]),
        _ => (p[0], p[1], p[2], p[3], &p[4..]),
    };
    let mut d = Distortion::default();
    match model {
        "SIMPLE_RADIAL" => d.k1 = rest[0],
        "RADIAL" => (d.k1, d.k2) = (rest[0], rest[1]),
        "OPENCV" | "FULL_OPENCV" => d = Distortion::from_opencv(rest).map_err(|e| e.to_string())?,
        _ => {}
    }
    let k = Intrinsics { width, height, fx, fy, cx: cx - 0.5, cy: cy - 0.5, skew: 0.0 };
    k.validate().map_err(|e| e.to_string())?;
    Ok((k, d))
}

/// The pose of a COLMAP image: world → camera quaternion `(qw, qx, qy, qz)` and translation.
fn colmap_pose(q: [f64; 4], t: [f64; 3]) -> Result<DAffine3, String> {
    let q = DQuat::from_xyzw(q[1], q[2], q[3], q[0]);
    if !q.is_finite() || (q.length() - 1.0).abs() > 1e-3 {
        let (w, x, y, z) = (num(q.w), num(q.x), num(q.y), num(q.z));
        return Err(format!("quaternion (w, x, y, z) = ({w}, {x}, {y}, {z}) is not a unit quaternion"));
    }
    let t = DVec3::from_array(t);
    if !t.is_finite() {
        return Err("translation must be finite".into());
    }
    Ok(world_from_camera_of(DMat3::from_quat(q.normalize()), t))
}

/// One image of a model: name, quaternion, translation, camera id, and where it was read (for
/// messages).
struct ColmapImage {
    name: String,
    q: [f64; 4],
    t: [f64; 3],
    camera_id: u64,
    place: String,
}

type ColmapCameras = Vec<(u64, Intrinsics, Distortion)>;

fn read_cameras_txt(path: &Path) -> Result<ColmapCameras, IoError> {
    let text = crate::read_input_text(path, "COLMAP cameras.txt")?;
    let mut cameras: ColmapCameras = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let bad = |why: String| IoError::invalid(path, format!("line {}: {why}", n + 1));
        let t: Vec<&str> = line.split_whitespace().collect();
        if t.len() < 4 {
            return Err(bad("expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...".into()));
        }
        let id: u64 = t[0].parse().map_err(|_| bad(format!("camera id `{}` is not an integer", t[0])))?;
        let pixels = |what: &str, v: &str| {
            v.parse::<u32>().map_err(|_| {
                bad(format!("{what} `{v}` is not a positive whole number of pixels (at most {})", u32::MAX))
            })
        };
        let (width, height) = (pixels("width", t[2])?, pixels("height", t[3])?);
        let p: Vec<f64> = t[4..]
            .iter()
            .map(|s| s.parse::<f64>().map_err(|_| bad(format!("parameter `{s}` is not a number"))))
            .collect::<Result<_, _>>()?;
        let (k, d) = colmap_camera(t[1], width, height, &p).map_err(bad)?;
        if let Some(why) = principal_point_outside(&k) {
            log::warn!("{}: line {}: camera id {id}: {why}", path.display(), n + 1);
        }
        if cameras.iter().any(|c| c.0 == id) {
            return Err(bad(format!("camera id {id} appears twice")));
        }
        cameras.push((id, k, d));
    }
    Ok(cameras)
}

fn read_images_txt(path: &Path) -> Result<Vec<ColmapImage>, IoError> {
    let text = crate::read_input_text(path, "COLMAP images.txt")?;
    let mut out = Vec::new();
    // Each image id and the line it was read on.
    let mut ids: Vec<(u64, usize)> = Vec::new();
    let mut lines = text.lines().enumerate();
    while let Some((n, line)) = lines.next() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let bad = |why: String| IoError::invalid(path, format!("line {}: {why}", n + 1));
        let t: Vec<&str> = line.split_whitespace().collect();
        if t.len() == 9 && t.iter().all(|s| s.parse::<f64>().is_ok()) {
            return Err(bad(format!("image id {} has an empty name", t[0])));
        }
        if t.len() < 10 {
            return Err(bad("expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME".into()));
        }
        let v: Vec<f64> = t[1..8]
            .iter()
            .map(|s| s.parse::<f64>().map_err(|_| bad(format!("`{s}` is not a number"))))
            .collect::<Result<_, _>>()?;
        let camera_id: u64 = t[8].parse().map_err(|_| bad(format!("camera id `{}` is not an integer", t[8])))?;
        // COLMAP's key of an image: one id twice is two models' files pasted together.
        let id: u64 = t[0].parse().map_err(|_| bad(format!("image id `{}` is not an integer", t[0])))?;
        if let Some((_, first)) = ids.iter().find(|(i, _)| *i == id) {
            return Err(bad(format!("image id {id} appears twice (first on line {})", first + 1)));
        }
        ids.push((id, n));
        // As COLMAP's own reader: the name is the tenth field (names cannot hold spaces). COLMAP
        // writes a name with spaces as it is, so text after the name is the rest of it: read
        // alone, the first word would be looked up as the image, another image or none.
        if t.len() > 10 {
            return Err(bad(format!(
                "the image name `{}` is followed by `{}`: a COLMAP image name cannot hold spaces (COLMAP's own \
                 reader takes the first word alone); rename the image files without spaces and export the model again",
                t[9],
                excerpt(&t[10..].join(" "))
            )));
        }
        out.push(ColmapImage {
            name: t[9].to_string(),
            q: [v[0], v[1], v[2], v[3]],
            t: [v[4], v[5], v[6]],
            camera_id,
            place: format!("line {}", n + 1),
        });
        // The next line lists the image's 2D points (empty when it has none); it is checked, not
        // read, so that a file without these lines is refused rather than read as every other image.
        for (m, points) in lines.by_ref() {
            if points.trim_start().starts_with('#') {
                continue;
            }
            if !is_points2d_line(points) {
                return Err(IoError::invalid(
                    path,
                    format!(
                        "line {}: expected the POINTS2D line of image {} (X Y POINT3D_ID triples), got `{}`; every \
                         image takes two lines, its own and the line of its 2D points (empty when it has none)",
                        m + 1,
                        t[0],
                        excerpt(points.trim())
                    ),
                ));
            }
            break;
        }
    }
    Ok(out)
}

/// Whether `line` is a POINTS2D line of `images.txt`: whole `X Y POINT3D_ID` triples (none for
/// an image without 2D points), the coordinates numbers and the id an integer (−1 for none).
fn is_points2d_line(line: &str) -> bool {
    let t: Vec<&str> = line.split_whitespace().collect();
    t.len().is_multiple_of(3)
        && t.chunks(3)
            .all(|p| p[0].parse::<f64>().is_ok() && p[1].parse::<f64>().is_ok() && p[2].parse::<i64>().is_ok())
}

/// `text` cut to its first 80 characters (with `…` when cut), for messages.
fn excerpt(text: &str) -> String {
    match text.char_indices().nth(80) {
        Some((i, _)) => format!("{}…", &text[..i]),
        None => text.to_string(),
    }
}

/// Little-endian reads from a byte slice that fail, rather than panic, past its end.
struct Bytes<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Bytes<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.data.len());
        let Some(end) = end else {
            return Err(format!("truncated: needs {n} more byte(s) at byte {} of {}", self.at, self.data.len()));
        };
        let s = &self.data[self.at..end];
        self.at = end;
        Ok(s)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N)?);
        Ok(a)
    }

    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    fn i32(&mut self) -> Result<i32, String> {
        Ok(i32::from_le_bytes(self.array()?))
    }

    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.array()?))
    }

    /// Refuses bytes after the last of the `count` records the file announced (`what`): a
    /// count that is too small, or a file of another kind, would otherwise lose the rest.
    fn end(&self, count: u64, what: &str) -> Result<(), String> {
        match self.data.len() - self.at {
            0 => Ok(()),
            extra => Err(format!(
                "{extra} bytes follow the last of the {count} {what} its count announces (a wrong count or a \
                 file of another format)"
            )),
        }
    }

    /// A NUL-terminated UTF-8 string.
    fn c_string(&mut self) -> Result<String, String> {
        let len = self.data[self.at..].iter().position(|&b| b == 0).ok_or("unterminated image name")?;
        let s = self.take(len)?;
        self.at += 1;
        String::from_utf8(s.to_vec()).map_err(|_| "image name is not UTF-8".to_string())
    }
}

/// `cameras.bin`: `u64` count, then per camera `i32` id, `i32` model id, `u64` width, `u64`
/// height and the model's parameters as `f64` (COLMAP `WriteCamerasBinary`).
fn read_cameras_bin(path: &Path) -> Result<ColmapCameras, IoError> {
    let data = crate::read_input(path, "COLMAP cameras.bin")?;
    let mut b = Bytes { data: &data, at: 0 };
    let mut run = || -> Result<ColmapCameras, String> {
        let n = b.u64()?;
        let mut cameras: ColmapCameras = Vec::new();
        for i in 0..n {
            let id = b.i32()?;
            let model_id = b.i32()?;
            let (model, count) = usize::try_from(model_id)
                .ok()
                .and_then(|m| COLMAP_MODELS.get(m))
                .copied()
                .ok_or_else(|| format!("camera id {id} (entry {i}): unknown model id {model_id}"))?;
            let (width, height) = (b.u64()?, b.u64()?);
            let params = (0..count).map(|_| b.f64()).collect::<Result<Vec<_>, _>>()?;
            let size = |v: u64| u32::try_from(v).map_err(|_| format!("camera id {id}: size {v} is too large"));
            let (k, d) = colmap_camera(model, size(width)?, size(height)?, &params)
                .map_err(|e| format!("camera id {id}: {e}"))?;
            if let Some(why) = principal_point_outside(&k) {
                log::warn!("{}: camera id {id}: {why}", path.display());
            }
            let id = u64::try_from(id).map_err(|_| format!("camera id {id} is negative"))?;
            if cameras.iter().any(|c| c.0 == id) {
                return Err(format!("camera id {id} appears twice"));
            }
            cameras.push((id, k, d));
        }
        b.end(n, "cameras")?;
        Ok(cameras)
    };
    run().map_err(|e| IoError::invalid(path, e))
}

/// `images.bin`: `u64` count, then per image `i32` id, quaternion `qw qx qy qz` and translation
/// as `f64`, `i32` camera id, the NUL-terminated name, a `u64` count of 2D points and 24 bytes
/// per point (COLMAP `WriteImagesBinary`).
fn read_images_bin(path: &Path) -> Result<Vec<ColmapImage>, IoError> {
    let data = crate::read_input(path, "COLMAP images.bin")?;
    let mut b = Bytes { data: &data, at: 0 };
    let mut run = || -> Result<Vec<ColmapImage>, String> {
        let n = b.u64()?;
        let mut out = Vec::new();
        let mut ids = Vec::new();
        for _ in 0..n {
            let image_id = b.i32()?;
            let q = [b.f64()?, b.f64()?, b.f64()?, b.f64()?];
            let t = [b.f64()?, b.f64()?, b.f64()?];
            let camera_id = b.i32()?;
            let name = b.c_string()?;
            if name.is_empty() {
                return Err(format!("image id {image_id} has an empty name"));
            }
            let points = b.u64()?;
            let skip = usize::try_from(points).ok().and_then(|p| p.checked_mul(24)).ok_or("too many 2D points")?;
            b.take(skip)?;
            let camera_id =
                u64::try_from(camera_id).map_err(|_| format!("image {name}: camera id {camera_id} is negative"))?;
            // COLMAP's key of an image: one id twice is two models' files pasted together.
            if ids.contains(&image_id) {
                return Err(format!("image id {image_id} ({name}) appears twice"));
            }
            ids.push(image_id);
            out.push(ColmapImage { name, q, t, camera_id, place: format!("image id {image_id}") });
        }
        b.end(n, "images")?;
        Ok(out)
    };
    run().map_err(|e| IoError::invalid(path, e))
}

/// Reads a COLMAP model in `dir` (`sparse/0` of a COLMAP project): `cameras.bin` and
/// `images.bin` when both exist, else `cameras.txt` and `images.txt`, as `(image name, camera)`
/// in the order of the images file (see the module docs for the conventions).
pub fn read_colmap(dir: &Path) -> Result<Vec<(String, Camera)>, IoError> {
    let (bin_cams, bin_imgs) = (dir.join("cameras.bin"), dir.join("images.bin"));
    let (cams, imgs) = (dir.join("cameras.txt"), dir.join("images.txt"));
    let (cameras, images, img_path) = if bin_cams.is_file() && bin_imgs.is_file() {
        (read_cameras_bin(&bin_cams)?, read_images_bin(&bin_imgs)?, bin_imgs)
    } else if cams.is_file() && imgs.is_file() {
        (read_cameras_txt(&cams)?, read_images_txt(&imgs)?, imgs)
    } else {
        return Err(IoError::invalid(dir, colmap_model_missing(dir)));
    };
    let mut out = Vec::with_capacity(images.len());
    for im in images {
        let bad = |why: String| IoError::invalid(&img_path, format!("{}: {why}", im.place));
        let (_, k, d) = cameras.iter().find(|c| c.0 == im.camera_id).ok_or_else(|| {
            bad(format!("image {} uses camera id {}, which the cameras file does not define", im.name, im.camera_id))
        })?;
        if out.iter().any(|(name, _)| *name == im.name) {
            return Err(bad(format!("image {} is listed twice; every image has one pose", im.name)));
        }
        let pose = colmap_pose(im.q, im.t).map_err(bad)?;
        out.push((im.name, Camera { intrinsics: *k, distortion: *d, world_from_camera: pose, lens: None }));
    }
    if out.is_empty() {
        return Err(IoError::invalid(&img_path, "no images"));
    }
    Ok(out)
}

/// Why `dir` holds no whole COLMAP model: which of its four files it has, and where a model
/// is when `dir` is a COLMAP project or its `sparse` folder (`sparse/0`, `0`).
fn colmap_model_missing(dir: &Path) -> String {
    if !dir.is_dir() {
        let what = if dir.exists() { "is not a folder" } else { "does not exist" };
        return format!("{what}; give the COLMAP model folder (holding cameras.txt and images.txt, or .bin)");
    }
    let files = ["cameras.bin", "images.bin", "cameras.txt", "images.txt"];
    let present: Vec<&str> = files.into_iter().filter(|f| dir.join(f).is_file()).collect();
    let has_model = |d: &Path| {
        (d.join("cameras.bin").is_file() && d.join("images.bin").is_file())
            || (d.join("cameras.txt").is_file() && d.join("images.txt").is_file())
    };
    let inner = ["sparse/0", "0", "sparse"].into_iter().map(|s| dir.join(s)).find(|d| has_model(d));
    let found = if present.is_empty() {
        "holds no COLMAP model file".to_string()
    } else {
        format!("holds {} alone", present.join(" and "))
    };
    match inner {
        Some(model) => format!("{found}; its model is in {}: give that folder", model.display()),
        None => format!(
            "{found}; a COLMAP model is cameras.txt with images.txt, or cameras.bin with images.bin (`colmap \
             model_converter --output_type TXT` writes the text pair)"
        ),
    }
}

/// Writes a COLMAP binary model (`cameras.bin`, `images.bin`) in `dir`, one camera per image,
/// with models `PINHOLE` or `FULL_OPENCV` and no 2D points. Pixel centres are shifted to
/// COLMAP's convention (`cx_file = cx + ½`); poses are written world → camera. A camera with
/// skew is refused: no COLMAP model holds it.
pub fn write_colmap_bin(dir: &Path, images: &[(String, Camera)]) -> Result<(), IoError> {
    let mut cams = Vec::new();
    let mut imgs = Vec::new();
    cams.extend((images.len() as u64).to_le_bytes());
    imgs.extend((images.len() as u64).to_le_bytes());
    for (i, (name, cam)) in images.iter().enumerate() {
        let k = &cam.intrinsics;
        if k.skew != 0.0 {
            return Err(IoError::invalid(
                dir.join("cameras.bin"),
                format!("camera of image {name} has skew {}, which no COLMAP camera model holds", k.skew),
            ));
        }
        let id = i as i32 + 1;
        let mut params = vec![k.fx, k.fy, k.cx + 0.5, k.cy + 0.5];
        let model: i32 = if cam.distortion.is_identity() {
            1
        } else {
            let d = &cam.distortion;
            params.extend([d.k1, d.k2, d.p1, d.p2, d.k3, d.k4, d.k5, d.k6]);
            6
        };
        cams.extend(id.to_le_bytes());
        cams.extend(model.to_le_bytes());
        cams.extend(u64::from(k.width).to_le_bytes());
        cams.extend(u64::from(k.height).to_le_bytes());
        params.iter().for_each(|p| cams.extend(p.to_le_bytes()));
        let camera_from_world = cam.camera_from_world();
        let q = DQuat::from_mat3(&camera_from_world.matrix3).normalize();
        imgs.extend(id.to_le_bytes());
        [q.w, q.x, q.y, q.z].iter().chain(camera_from_world.translation.to_array().iter()).for_each(|v| {
            imgs.extend(v.to_le_bytes());
        });
        imgs.extend(id.to_le_bytes());
        imgs.extend(name.as_bytes());
        imgs.push(0);
        imgs.extend(0u64.to_le_bytes());
    }
    atomic_write(&dir.join("cameras.bin"), |w| w.write_all(&cams))?;
    atomic_write(&dir.join("images.bin"), |w| w.write_all(&imgs))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rodrigues_round_trips_including_near_zero_and_pi() {
        for r in [
            DVec3::new(0.1, -0.2, 0.3),
            DVec3::new(1e-9, 2e-9, -1e-9),
            DVec3::ZERO,
            DVec3::new(0.0, 0.0, std::f64::consts::PI - 1e-7),
            DVec3::new(2.0, 1.0, -0.5).normalize() * 3.0,
        ] {
            let m = rodrigues_to_matrix(r);
            let back = matrix_to_rodrigues(m);
            assert!((back - r).length() < 1e-12, "{r} -> {back}");
            let q = DMat3::from_quat(DQuat::from_scaled_axis(r));
            assert!((m - q).to_cols_array().iter().all(|e| e.abs() < 1e-15));
        }
    }

    /// A "billion laughs" document: level `i` lists its predecessor 9 times, so level `n - 1`
    /// expands to 9ⁿ nodes.
    fn nested_aliases(n: usize) -> String {
        let mut s = String::from("%YAML 1.2\n---\na: &a [x]\n");
        for i in 0..n {
            let prev = if i == 0 { "a".to_string() } else { format!("l{}", i - 1) };
            s.push_str(&format!("l{i}: &l{i} [{}]\n", vec![format!("*{prev}"); 9].join(",")));
        }
        s
    }

    #[test]
    fn nested_aliases_are_refused_before_they_expand() {
        let dir = tempfile::tempdir().unwrap();
        let bomb = dir.path().join("bomb.yml");
        // About 10⁶ nodes once expanded (small enough that even expanding it would not exhaust
        // the memory; each level more multiplies it by 9).
        std::fs::write(&bomb, nested_aliases(6)).unwrap();
        let started = std::time::Instant::now();
        let e = read_opencv(&bomb).unwrap_err().to_string();
        assert!(e.contains("bomb.yml") && e.contains("aliases") && e.contains("100000"), "{e}");
        assert!(started.elapsed().as_secs_f64() < 5.0);
        // A few shared nodes are still read as before (and then as a calibration).
        let few = dir.path().join("few.yml");
        std::fs::write(&few, nested_aliases(2)).unwrap();
        let e = read_opencv(&few).unwrap_err().to_string();
        assert!(!e.contains("aliases"), "{e}");
        let mut count = AliasCount::default();
        yaml_rust2::parser::Parser::new_from_str(&nested_aliases(3)).load(&mut count, true).unwrap();
        // `a` is 2 nodes (the list and `x`), `l0` 1 + 9 × 2, `l1` 1 + 9 × 19; `l2` copies `l1` 9 times.
        assert_eq!(count.from_aliases, 9 * 2 + 9 * 19 + 9 * 172);
    }

    /// A calibration in JSON with a NaN where a number belongs (as Python's `json.dump` writes
    /// it) names the NaN and its key.
    #[test]
    fn a_nan_in_a_json_calibration_is_named_with_its_key() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("rig.json");
        std::fs::write(&file, "{\n  \"image_width\": 32,\n  \"camera_matrix\": {\"rows\": 1, \"data\": [1, NaN]}\n}\n")
            .unwrap();
        let e = read_opencv(&file).unwrap_err().to_string();
        assert!(e.contains("rig.json: malformed JSON: line 3 column"), "{e}");
        assert!(e.contains("at `camera_matrix.data[1]`: NaN is not a JSON number"), "{e}");
    }

    /// With pixel centres at integers an image of n pixels spans −½ to n − ½: a principal point
    /// on that edge is inside, one beyond it, in either direction, is not.
    #[test]
    fn a_principal_point_is_outside_only_beyond_the_images_edges() {
        let k = |cx: f64, cy: f64| Intrinsics { width: 40, height: 30, fx: 50.0, fy: 50.0, cx, cy, skew: 0.0 };
        for (cx, cy) in [(-0.5, -0.5), (39.5, 29.5), (19.5, 14.5), (39.5, -0.5)] {
            assert_eq!(principal_point_outside(&k(cx, cy)), None, "({cx}, {cy})");
        }
        for (cx, cy) in [(-0.51, 10.0), (39.51, 10.0), (10.0, -0.51), (10.0, 29.51), (80.0, 60.0)] {
            let why = principal_point_outside(&k(cx, cy)).unwrap_or_else(|| panic!("({cx}, {cy}) is outside"));
            assert!(why.contains(&format!("({}, {})", num(cx), num(cy))) && why.contains("40x30 image"), "{why}");
        }
    }

    /// XML nested beyond any calibration is refused before parsing (beyond 64 levels) or while
    /// reading (beyond 32), with the right words; empty elements, closed elements, comments and
    /// the declaration do not deepen it.
    #[test]
    fn deeply_nested_xml_is_refused_and_flat_xml_is_not() {
        let nested = |n: usize| format!("{}{}", "<a>".repeat(n), "</a>".repeat(n));
        assert_eq!(xml_nesting(&nested(5)), 5);
        let flat =
            format!("<?xml version=\"1.0\"?><!-- <x> --><r>{}{}<b/></r>", "<c/>".repeat(100), nested(3).repeat(50));
        assert_eq!(xml_nesting(&flat), 4);
        assert_eq!(xml_nesting("<a><b></b><c><d/></c></a>"), 2);
        assert_eq!(xml_nesting("<a"), 1, "an unclosed tag at the end");
        let dir = tempfile::tempdir().unwrap();
        let storage = |inner: String| format!("<?xml version=\"1.0\"?>\n<opencv_storage>{inner}</opencv_storage>\n");
        let deep = dir.path().join("deep.xml");
        std::fs::write(&deep, storage(nested(40))).unwrap();
        let e = read_opencv(&deep).unwrap_err().to_string();
        assert!(e.contains("deep.xml") && e.contains("nested more than 32 deep (line"), "{e}");
        std::fs::write(&deep, storage(nested(70))).unwrap();
        let e = read_opencv(&deep).unwrap_err().to_string();
        assert!(e.contains("nested more than 64 deep; not a calibration file"), "{e}");
        // 30 levels of nesting is read (and then refused for holding no camera).
        std::fs::write(&deep, storage(format!("<a>{}</a>", nested(29)))).unwrap();
        let e = read_opencv(&deep).unwrap_err().to_string();
        assert!(!e.contains("nested"), "{e}");
    }

    /// Names that look like a camera's distortion but are not read are the ones warned about.
    #[test]
    fn nodes_named_like_a_distortion_are_told_from_others() {
        let names = [
            "dist_coeffs",
            "distCoeffs",
            "D",
            "d",
            "kc",
            "KC",
            "Distortion_Model",
            "distortion_coefficients",
            "distance",
            "Distance_To_Board",
            "camera_matrix",
            "DD",
            "k1",
        ];
        let found = distortion_lookalikes(names.iter().map(|n| (*n, *n)));
        assert_eq!(found, ["dist_coeffs", "distCoeffs", "D", "d", "kc", "KC"]);
        // The node is named, its base (without the camera's suffix) judged.
        assert_eq!(distortion_lookalikes([("dist_left", "dist"), ("R_left", "R")].into_iter()), ["dist_left"]);
    }

    #[test]
    fn long_text_is_cut_to_eighty_characters_in_messages() {
        assert_eq!(excerpt("short"), "short");
        let eighty = "é".repeat(80);
        assert_eq!(excerpt(&eighty), eighty);
        assert_eq!(excerpt(&format!("{eighty}x")), format!("{eighty}…"));
    }

    /// Suffixed keys carry the camera's name, so it must be a plain word; a single camera named
    /// after the file is written unsuffixed, whatever its name. Other extensions are refused.
    #[test]
    fn written_camera_names_must_make_keys_and_the_extension_a_format() {
        let k = Intrinsics { width: 40, height: 30, fx: 50.0, fy: 50.0, cx: 19.5, cy: 14.5, skew: 0.0 };
        let cam = Camera::look_at(k, DVec3::new(0.0, -50.0, 0.0), DVec3::ZERO, DVec3::Z);
        let dir = tempfile::tempdir().unwrap();
        for bad in ["left cam", "", "a:b"] {
            let cams = vec![(bad.to_string(), cam.clone()), ("right".to_string(), cam.clone())];
            let e = write_opencv(&dir.path().join("rig.yml"), &cams).unwrap_err().to_string();
            assert!(e.contains(&format!("camera name `{bad}` must be letters, digits")), "{e}");
        }
        let plain = dir.path().join("cam 1.yml");
        write_opencv(&plain, &[("cam 1".to_string(), cam.clone())]).unwrap();
        assert_eq!(read_opencv(&plain).unwrap()[0].0, "cam 1");
        let cams = vec![("a-1".to_string(), cam.clone()), ("b_2".to_string(), cam.clone())];
        for ext in ["yml", "yaml", "xml", "json", "YML"] {
            let path = dir.path().join(format!("rig.{ext}"));
            write_opencv(&path, &cams).unwrap();
            let names: Vec<String> = read_opencv(&path).unwrap().into_iter().map(|(n, _)| n).collect();
            assert_eq!(names, ["a-1", "b_2"], "{ext}");
        }
        let e = write_opencv(&dir.path().join("rig.txt"), &cams).unwrap_err().to_string();
        assert!(e.contains("rig.txt") && e.contains("must end in .yml, .yaml, .xml or .json"), "{e}");
    }
}
