//! Cameras given as 3 × 4 projection matrices or as the 11 coefficients of the direct linear
//! transform (DLT), in text files.
//!
//! A projection matrix `P` maps a world point `X` to the pixel `(u, v) = (p₁·X̃, p₂·X̃) / p₃·X̃`
//! (`X̃ = (x, y, z, 1)`, `pᵢ` the rows of `P`). The 11 DLT coefficients `L1 … L11` are the
//! same map with `P` scaled so that its last entry is 1:
//! `u = (L1 x + L2 y + L3 z + L4) / (L9 x + L10 y + L11 z + 1)`,
//! `v = (L5 x + L6 y + L7 z + L8) / (L9 x + L10 y + L11 z + 1)`.
//! Pixels are in OpenCV's convention, fluidnerf's: `u` to the right, `v` down, `(0, 0)` the
//! centre of the top-left pixel. Coefficients whose `v` counts up from the image's bottom
//! (`v' = H − v`, as DLTdv and Easy-WAND write them) are flipped by [`flip_v`].
//!
//! # Files
//! Numbers separated by blanks, commas or semicolons; `#` and `%` start a comment; empty
//! lines are skipped. A first line of names instead of numbers names the columns' cameras.
//! The numbers' shape says what they are:
//! - 3 rows of 4: one camera's `P`;
//! - one row of 11 or of 12: one camera's DLT coefficients or its `P` row by row;
//! - 11 rows of N: N cameras' DLT coefficients, one camera per column (the layout of a
//!   `*_dltCoefs.csv`); 12 rows of N: N cameras' `P`, each column `P` row by row — unless
//!   their first row counts 1, 2, …, N (or from 0) with no line of names above it: that row
//!   names the cameras above their DLT coefficients (images `1.png`, `2.png`, …), with a warning.
//!
//! A file of one camera names it after the file's stem (`cam3.txt` → `cam3`); a file of N
//! cameras after its line of names, else `cam1` … `camN`. A folder is read as all its `.txt`,
//! `.csv` and `.dat` files in name order; camera names must be unique.
//!
//! # From `P` to a camera
//! `P` is known up to a factor, its sign included. The sign is chosen so that the left 3 × 3
//! block `M` has a positive determinant (the scene then lies in front of the camera, at
//! positive depth), and `M = K R` is split by an RQ decomposition into an upper-triangular
//! `K` with a positive diagonal and a rotation `R`; `t = K⁻¹ p₄`, and `K` is scaled so that
//! `K₃₃ = 1`. The camera is then the pinhole `K` (focal lengths, principal point and skew)
//! at the world → camera pose `(R, t)`, without distortion: a projection matrix models none.
//! The image size is not part of `P`; the importer takes it from each camera's images.

use std::path::{Path, PathBuf};

use fluidnerf_core::glam::{DMat3, DVec3};
use fluidnerf_core::{num, Camera, Distortion, Intrinsics};

use crate::IoError;

/// How a camera's numbers were given.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProjectionForm {
    /// A 3 × 4 projection matrix.
    Matrix,
    /// 11 DLT coefficients (the matrix with its last entry 1).
    Dlt,
}

/// One camera's projection matrix as read from a file.
#[derive(Clone, Debug)]
pub struct ProjectionCamera {
    pub name: String,
    /// The file it was read from.
    pub file: PathBuf,
    pub form: ProjectionForm,
    /// `P`, row by row.
    pub matrix: [[f64; 4]; 3],
}

impl ProjectionCamera {
    /// This camera for images of `width` × `height` pixels ([`camera_from_projection`]), its
    /// v counted up from the image's bottom edge turned round first when `bottom_left_origin`
    /// ([`flip_v`]); an error names the file and the camera.
    pub fn camera(&self, width: u32, height: u32, bottom_left_origin: bool) -> Result<Camera, IoError> {
        let matrix = if bottom_left_origin { flip_v(self.matrix, height) } else { self.matrix };
        camera_from_projection(matrix, width, height)
            .map_err(|why| IoError::invalid(&self.file, format!("camera `{}`: {why}", self.name)))
    }
}

/// Extensions of the files a folder of projection matrices is read from.
const EXTENSIONS: [&str; 3] = ["txt", "csv", "dat"];

/// Reads the cameras of a file, or of every `.txt`, `.csv` and `.dat` file of a folder in name
/// order (module docs).
pub fn read_projection(path: &Path) -> Result<Vec<ProjectionCamera>, IoError> {
    let files = super::calibration_files(
        path,
        "projection matrix folder",
        &EXTENSIONS,
        |_| true,
        "the folder holds no .txt, .csv or .dat file of projection matrices",
    )?;
    let mut cameras: Vec<ProjectionCamera> = Vec::new();
    for file in &files {
        for cam in read_file(file)? {
            if let Some(first) = cameras.iter().find(|c| c.name == cam.name) {
                return Err(IoError::invalid(
                    file,
                    format!(
                        "camera `{}` is given twice: in {} and here; camera names must be unique",
                        cam.name,
                        first.file.display()
                    ),
                ));
            }
            cameras.push(cam);
        }
    }
    Ok(cameras)
}

/// The names of a file's first line, if it holds names, and its rows of numbers.
type Rows = (Option<Vec<String>>, Vec<Vec<f64>>);

/// The rows of numbers of a text file, and the names of its first line if it holds names.
fn parse_rows(path: &Path, text: &str) -> Result<Rows, IoError> {
    let mut names = None;
    let mut rows: Vec<Vec<f64>> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split(['#', '%']).next().unwrap_or("");
        let tokens: Vec<&str> =
            line.split(|c: char| c.is_whitespace() || c == ',' || c == ';').filter(|t| !t.is_empty()).collect();
        if tokens.is_empty() {
            continue;
        }
        let numbers: Vec<Option<f64>> = tokens.iter().map(|t| t.parse::<f64>().ok()).collect();
        if rows.is_empty() && names.is_none() && numbers.iter().all(Option::is_none) {
            names = Some(tokens.iter().map(|t| t.trim_matches('"').to_string()).collect());
            continue;
        }
        let mut row = Vec::with_capacity(tokens.len());
        for (t, n) in tokens.iter().zip(&numbers) {
            match n {
                Some(v) if v.is_finite() => row.push(*v),
                Some(_) => {
                    return Err(IoError::invalid(path, format!("line {}: `{t}` is not a finite number", i + 1)));
                }
                None => return Err(IoError::invalid(path, format!("line {}: `{t}` is not a number", i + 1))),
            }
        }
        if let Some(first) = rows.first().filter(|r| r.len() != row.len()) {
            return Err(IoError::invalid(
                path,
                format!(
                    "line {} holds {} numbers where the lines before hold {}: every line of a file of projection \
                     matrices holds as many",
                    i + 1,
                    row.len(),
                    first.len()
                ),
            ));
        }
        rows.push(row);
    }
    Ok((names, rows))
}

/// Twelve lines of N ≥ 2 numbers whose first line counts 1, 2, …, N (or 0, 1, …, N − 1) are
/// the cameras' names above their 11 DLT coefficients, not 12 matrix entries per camera whose
/// first entries happen to count: names that are numbers (images `1.png`, `2.png`, …) read as
/// numbers. Said in a warning, with how to have the other reading.
fn numbered_names(path: &Path, (names, rows): Rows) -> Rows {
    let counts = |first: &[f64]| {
        first.len() >= 2 && [0.0, 1.0].iter().any(|&from| first.iter().enumerate().all(|(k, &v)| v == from + k as f64))
    };
    if names.is_some() || rows.len() != 12 || !counts(&rows[0]) {
        return (names, rows);
    }
    let numbered: Vec<String> = rows[0].iter().map(|v| format!("{v}")).collect();
    log::warn!(
        "{}: its first line ({}) is read as the cameras' names, above 11 DLT coefficients per camera; if it holds \
         the first of 12 projection-matrix entries per camera instead, add a line of names above it",
        path.display(),
        numbered.join(", ")
    );
    (Some(numbered), rows[1..].to_vec())
}

/// The matrix of 12 numbers given row by row, or of 11 DLT coefficients (last entry 1).
fn matrix_of(values: &[f64]) -> [[f64; 4]; 3] {
    let at = |i: usize| if i < values.len() { values[i] } else { 1.0 };
    [[at(0), at(1), at(2), at(3)], [at(4), at(5), at(6), at(7)], [at(8), at(9), at(10), at(11)]]
}

fn read_file(path: &Path) -> Result<Vec<ProjectionCamera>, IoError> {
    let text = crate::read_input_text(path, "projection matrix file")?;
    let (names, rows) = numbered_names(path, parse_rows(path, &text)?);
    let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("cam").to_string();
    let (n_rows, n_cols) = (rows.len(), rows.first().map_or(0, Vec::len));
    let one = |form, matrix| vec![ProjectionCamera { name: stem.clone(), file: path.to_path_buf(), form, matrix }];
    let cameras = match (n_rows, n_cols) {
        (0, _) => return Err(IoError::invalid(path, "holds no numbers")),
        (3, 4) => one(ProjectionForm::Matrix, matrix_of(&rows.concat())),
        (1, 11) => one(ProjectionForm::Dlt, matrix_of(&rows[0])),
        (1, 12) => one(ProjectionForm::Matrix, matrix_of(&rows[0])),
        (11 | 12, n) => {
            let form = if n_rows == 11 { ProjectionForm::Dlt } else { ProjectionForm::Matrix };
            let names: Vec<String> = match &names {
                Some(names) if names.len() == n => names.clone(),
                Some(names) => {
                    return Err(IoError::invalid(
                        path,
                        format!("its first line names {} cameras, but its columns hold {n}", names.len()),
                    ))
                }
                None if n == 1 => vec![stem.clone()],
                None => (1..=n).map(|k| format!("cam{k}")).collect(),
            };
            names
                .into_iter()
                .enumerate()
                .map(|(k, name)| {
                    let column: Vec<f64> = rows.iter().map(|r| r[k]).collect();
                    ProjectionCamera { name, file: path.to_path_buf(), form, matrix: matrix_of(&column) }
                })
                .collect()
        }
        (r, c) => {
            return Err(IoError::invalid(
                path,
                format!(
                    "holds {r} line(s) of {c} number(s); expected a 3 × 4 projection matrix (3 lines of 4), one \
                     camera's 11 DLT coefficients or 12 matrix entries on one line, or one camera per column: 11 \
                     lines of DLT coefficients or 12 of matrix entries row by row"
                ),
            ))
        }
    };
    if let Some(names) = &names {
        if n_rows == 3 || n_rows == 1 {
            return Err(IoError::invalid(
                path,
                format!(
                    "its first line holds names ({}), which only a file of one camera per column has",
                    names.join(", ")
                ),
            ));
        }
        let mut seen = std::collections::BTreeSet::new();
        if let Some(twice) = names.iter().find(|n| !seen.insert(n.as_str())) {
            return Err(IoError::invalid(path, format!("its first line names camera `{twice}` twice")));
        }
        if let Some(bad) = names.iter().find(|n| n.is_empty() || n.contains(['/', '\\'])) {
            return Err(IoError::invalid(path, format!("`{bad}` in its first line is not a camera name")));
        }
    }
    Ok(cameras)
}

/// The matrix whose `v` is `height − v` of `p`'s: `p` read with its image origin at the
/// bottom-left, `v` counting up.
pub fn flip_v(p: [[f64; 4]; 3], height: u32) -> [[f64; 4]; 3] {
    let h = f64::from(height);
    let mut q = p;
    for j in 0..4 {
        q[1][j] = h * p[2][j] - p[1][j];
    }
    q
}

/// The pinhole camera of projection matrix `p` for images of `width` × `height` pixels
/// (module docs): an error says why `p` is no camera.
pub fn camera_from_projection(p: [[f64; 4]; 3], width: u32, height: u32) -> Result<Camera, String> {
    if p.iter().flatten().any(|v| !v.is_finite()) {
        return Err("the matrix holds a value that is not finite".into());
    }
    // A matrix is a camera at any scale: brought to a largest entry of 1, one written at 1e300
    // no longer overflows the decomposition ("values must be finite") and one at 1e-120 no
    // longer underflows its determinant to 0 ("singular").
    let largest = p.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if largest == 0.0 {
        return Err(
            "the matrix is zero throughout, so its left 3 × 3 block is singular: it does not come from a camera that \
             images a volume"
                .into(),
        );
    }
    let p = p.map(|r| r.map(|v| v / largest));
    let row = |i: usize| DVec3::new(p[i][0], p[i][1], p[i][2]);
    let m = DMat3::from_cols(row(0), row(1), row(2)).transpose();
    let det = m.determinant();
    let scale = row(0).length() * row(1).length() * row(2).length();
    // Finite entries give a finite determinant and scale.
    if det.abs() <= 1e-12 * scale || scale == 0.0 {
        return Err(format!(
            "its left 3 × 3 block is singular (determinant {} against {} for its rows' lengths): the matrix does \
             not come from a camera that images a volume",
            num(det),
            num(scale)
        ));
    }
    let sign = det.signum();
    let (m1, m2, m3) = (row(0) * sign, row(1) * sign, row(2) * sign);
    let p4 = DVec3::new(p[0][3], p[1][3], p[2][3]) * sign;
    // RQ by Gram–Schmidt from the last row up: M = K R, K upper triangular, diagonal > 0.
    let k33 = m3.length();
    let r3 = m3 / k33;
    let k23 = m2.dot(r3);
    let q2 = m2 - r3 * k23;
    let k22 = q2.length();
    let r2 = q2 / k22;
    let (k13, k12) = (m1.dot(r3), m1.dot(r2));
    let q1 = m1 - r3 * k13 - r2 * k12;
    let k11 = q1.length();
    let r1 = q1 / k11;
    let k = DMat3::from_cols(DVec3::new(k11, 0.0, 0.0), DVec3::new(k12, k22, 0.0), DVec3::new(k13, k23, k33));
    let t = k.inverse() * p4;
    let rotation = DMat3::from_cols(r1, r2, r3).transpose();
    let intrinsics =
        Intrinsics { width, height, fx: k11 / k33, fy: k22 / k33, cx: k13 / k33, cy: k23 / k33, skew: k12 / k33 };
    let camera = Camera {
        intrinsics,
        distortion: Distortion::default(),
        world_from_camera: super::world_from_camera_of(rotation, t),
        lens: None,
    };
    camera.validate().map_err(|e| e.to_string())?;
    Ok(camera)
}

/// The projection matrix `K [R | t]` of `camera`'s pinhole (its distortion left out), scaled so
/// that `K₃₃ = 1`.
pub fn projection_of(camera: &Camera) -> [[f64; 4]; 3] {
    let k = &camera.intrinsics;
    let kmat = DMat3::from_cols(DVec3::new(k.fx, 0.0, 0.0), DVec3::new(k.skew, k.fy, 0.0), DVec3::new(k.cx, k.cy, 1.0));
    let camera_from_world = camera.world_from_camera.inverse();
    let km = kmat * camera_from_world.matrix3;
    let kt = kmat * camera_from_world.translation;
    let mut p = [[0.0; 4]; 3];
    for (i, row) in p.iter_mut().enumerate() {
        *row = [km.row(i).x, km.row(i).y, km.row(i).z, kt[i]];
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;
    use fluidnerf_core::glam::DAffine3;

    fn camera(skew: f64, axis: DVec3, angle: f64, t: DVec3) -> Camera {
        let rotation = DMat3::from_axis_angle(axis.normalize(), angle);
        Camera {
            intrinsics: Intrinsics { width: 640, height: 480, fx: 812.5, fy: 790.25, cx: 330.75, cy: 236.5, skew },
            distortion: Distortion::default(),
            world_from_camera: DAffine3::from_mat3_translation(rotation, t).inverse(),
            lens: None,
        }
    }

    fn close(a: &Camera, b: &Camera) {
        let (ka, kb) = (&a.intrinsics, &b.intrinsics);
        for (x, y) in [(ka.fx, kb.fx), (ka.fy, kb.fy), (ka.cx, kb.cx), (ka.cy, kb.cy), (ka.skew, kb.skew)] {
            assert!((x - y).abs() < 1e-9 * (1.0 + x.abs()), "{x} against {y}");
        }
        let (ma, mb) = (a.world_from_camera.to_cols_array(), b.world_from_camera.to_cols_array());
        for (x, y) in ma.iter().zip(mb) {
            assert!((x - y).abs() < 1e-9 * (1.0 + x.abs()), "{ma:?} against {mb:?}");
        }
    }

    /// A camera's matrix, at any scale and of either sign, gives back the camera; so do its
    /// 11 DLT coefficients.
    #[test]
    fn a_matrix_at_any_scale_and_sign_gives_back_its_camera() {
        let cams = [
            camera(0.0, DVec3::new(0.3, -1.0, 0.2), 2.1, DVec3::new(0.5, -0.25, 700.0)),
            camera(1.75, DVec3::new(1.0, 0.1, 0.0), -0.4, DVec3::new(-12.0, 3.0, 250.0)),
            camera(-0.5, DVec3::new(0.0, 0.0, 1.0), 3.0, DVec3::new(1.0, 2.0, 40.0)),
        ];
        for cam in &cams {
            let p = projection_of(cam);
            for s in [1.0, -1.0, 1e-4, -3.7e5] {
                let scaled = p.map(|r| r.map(|v| v * s));
                close(&camera_from_projection(scaled, 640, 480).unwrap(), cam);
            }
            let dlt: Vec<f64> = p.iter().flatten().map(|v| v / p[2][3]).take(11).collect();
            close(&camera_from_projection(matrix_of(&dlt), 640, 480).unwrap(), cam);
        }
    }

    /// The decomposed camera maps world points to the pixels the matrix gives (an independent
    /// check of the pixel convention: no half-pixel shift).
    #[test]
    fn the_camera_projects_points_where_the_matrix_does() {
        let p = [[700.0, 3.0, 300.0, 1200.0], [-4.0, 720.0, 250.0, -800.0], [0.01, -0.02, 1.0, 900.0]];
        let cam = camera_from_projection(p, 640, 480).unwrap();
        for x in [DVec3::new(0.0, 0.0, 0.0), DVec3::new(30.0, -20.0, 50.0), DVec3::new(-45.0, 10.0, -60.0)] {
            let w = p[2][0] * x.x + p[2][1] * x.y + p[2][2] * x.z + p[2][3];
            let u = (p[0][0] * x.x + p[0][1] * x.y + p[0][2] * x.z + p[0][3]) / w;
            let v = (p[1][0] * x.x + p[1][1] * x.y + p[1][2] * x.z + p[1][3]) / w;
            let xc = cam.world_from_camera.inverse().transform_point3(x);
            assert!(xc.z > 0.0);
            let k = &cam.intrinsics;
            let (a, b) = (xc.x / xc.z, xc.y / xc.z);
            let (uc, vc) = (k.fx * a + k.skew * b + k.cx, k.fy * b + k.cy);
            assert!((u - uc).abs() < 1e-9 && (v - vc).abs() < 1e-9, "({u}, {v}) against ({uc}, {vc})");
        }
    }

    /// Coefficients whose v counts up from the bottom give the camera whose v counts down.
    #[test]
    fn flipping_v_turns_a_bottom_left_origin_into_the_top_left() {
        let cam = camera(0.0, DVec3::new(0.2, 1.0, -0.3), 0.8, DVec3::new(2.0, -1.0, 500.0));
        let p = projection_of(&cam);
        // The same camera with v measured upwards: v' = 480 − v.
        let up = flip_v(p, 480);
        close(&camera_from_projection(flip_v(up, 480), 640, 480).unwrap(), &cam);
        let flipped = camera_from_projection(up, 640, 480).unwrap();
        assert!((flipped.intrinsics.cy - (480.0 - 236.5)).abs() < 1e-9);
    }

    #[test]
    fn matrices_that_are_no_camera_are_refused() {
        let singular = [[1.0, 2.0, 3.0, 4.0], [2.0, 4.0, 6.0, 1.0], [0.0, 0.0, 1.0, 5.0]];
        assert!(camera_from_projection(singular, 64, 64).unwrap_err().contains("singular"));
        assert!(camera_from_projection([[0.0; 4]; 3], 64, 64).unwrap_err().contains("singular"));
        let mut nan = projection_of(&camera(0.0, DVec3::X, 0.1, DVec3::new(0.0, 0.0, 10.0)));
        nan[1][2] = f64::NAN;
        assert!(camera_from_projection(nan, 64, 64).unwrap_err().contains("not finite"));
    }

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn files_are_read_by_their_shape() {
        let dir = tempfile::tempdir().unwrap();
        let m = write(dir.path(), "left.txt", "# P\n1 0 0 4\n0 1 0 5\n0 0 1 6\n");
        let c = read_projection(&m).unwrap();
        assert_eq!((c.len(), c[0].name.as_str(), c[0].form), (1, "left", ProjectionForm::Matrix));
        assert_eq!(c[0].matrix[1][3], 5.0);
        // One camera per column, with and without names; DLT's last entry is 1.
        let cols: String = (1..=11).map(|i| format!("{i},{}\n", 100 + i)).collect();
        let d = write(dir.path(), "coefs.csv", &cols);
        let c = read_projection(&d).unwrap();
        assert_eq!(c.iter().map(|c| c.name.as_str()).collect::<Vec<_>>(), ["cam1", "cam2"]);
        assert_eq!((c[1].matrix[2][2], c[1].matrix[2][3], c[1].form), (111.0, 1.0, ProjectionForm::Dlt));
        let named = write(dir.path(), "named.csv", &format!("a; b\n{cols}"));
        assert_eq!(read_projection(&named).unwrap()[1].name, "b");
        // A first line counting the cameras names them, above their DLT coefficients; under a
        // line of names, the same twelve lines are matrices.
        for (from, names) in [(1, ["1", "2"]), (0, ["0", "1"])] {
            let numbered = write(dir.path(), "numbered.csv", &format!("{from},{}\n{cols}", from + 1));
            let c = read_projection(&numbered).unwrap();
            assert_eq!(c.iter().map(|c| c.name.as_str()).collect::<Vec<_>>(), names);
            assert_eq!((c[1].matrix[2][2], c[1].form), (111.0, ProjectionForm::Dlt));
        }
        let matrices = write(dir.path(), "matrices.csv", &format!("p; q\n1,2\n{cols}"));
        let c = read_projection(&matrices).unwrap();
        assert_eq!((c[1].name.as_str(), c[1].form, c[1].matrix[0][0]), ("q", ProjectionForm::Matrix, 2.0));
        // Counting from 2 is not a line of names.
        let matrices = write(dir.path(), "counts.csv", &format!("2,3\n{cols}"));
        assert_eq!(read_projection(&matrices).unwrap()[0].form, ProjectionForm::Matrix);
        // One line of 11.
        let line = write(dir.path(), "one.dat", "1 2 3 4 5 6 7 8 9 10 11 % DLT\n");
        assert_eq!(read_projection(&line).unwrap()[0].matrix[2], [9.0, 10.0, 11.0, 1.0]);
    }

    #[test]
    fn malformed_files_are_refused_naming_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            ("ragged.txt", "1 2 3 4\n5 6 7\n0 0 1 1\n", "line 2 holds 3 numbers"),
            ("word.txt", "1 2 3 4\n5 six 7 8\n0 0 1 1\n", "line 2: `six` is not a number"),
            ("inf.txt", "1 2 3 4\n5 6 inf 8\n0 0 1 1\n", "line 2: `inf` is not a finite number"),
            ("shape.txt", "1 2 3\n4 5 6\n", "holds 2 line(s) of 3 number(s)"),
            ("empty.txt", "# nothing\n\n", "holds no numbers"),
        ];
        for (name, text, why) in cases {
            let path = write(dir.path(), name, text);
            let e = read_projection(&path).unwrap_err().to_string();
            assert!(e.contains(why) && e.contains(name), "{name}: {e}");
        }
        let three = format!("a b c\n{}", "1 2\n".repeat(11));
        let e = read_projection(&write(dir.path(), "three.csv", &three)).unwrap_err().to_string();
        assert!(e.contains("its first line names 3 cameras, but its columns hold 2"), "{e}");
        let names = format!("a a\n{}", "1 2\n".repeat(11));
        let e = read_projection(&write(dir.path(), "twice.csv", &names)).unwrap_err().to_string();
        assert!(e.contains("names camera `a` twice"), "{e}");
    }

    #[test]
    fn a_folder_refuses_a_camera_given_twice() {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path(), "a.txt", "1 0 0 4\n0 1 0 5\n0 0 1 6\n");
        write(dir.path(), "b.csv", &"1 2\n".repeat(11));
        write(dir.path(), "notes.md", "not read");
        assert_eq!(read_projection(dir.path()).unwrap().len(), 3);
        write(dir.path(), "c.txt", &format!("a x\n{}", "1 2\n".repeat(11)));
        let e = read_projection(dir.path()).unwrap_err().to_string();
        assert!(e.contains("camera `a` is given twice") && e.contains("c.txt"), "{e}");
    }

    /// `ProjectionCamera::camera` gives the decomposed camera, turning a bottom-left origin
    /// round first, and names the file and the camera when the matrix is no camera.
    #[test]
    fn a_read_camera_is_decomposed_with_its_origin_as_asked() {
        let cam = camera(0.5, DVec3::new(0.2, 1.0, -0.3), 0.8, DVec3::new(2.0, -1.0, 500.0));
        let read = ProjectionCamera {
            name: "left".into(),
            file: PathBuf::from("rig.txt"),
            form: ProjectionForm::Matrix,
            matrix: projection_of(&cam),
        };
        close(&read.camera(640, 480, false).unwrap(), &cam);
        let up = ProjectionCamera { matrix: flip_v(read.matrix, 480), ..read.clone() };
        close(&up.camera(640, 480, true).unwrap(), &cam);
        let from_top = up.camera(640, 480, false).unwrap();
        assert!((from_top.intrinsics.cy - (480.0 - 236.5)).abs() < 1e-9, "{}", from_top.intrinsics.cy);
        let e = ProjectionCamera { matrix: [[0.0; 4]; 3], ..read }.camera(640, 480, false).unwrap_err().to_string();
        assert!(e.contains("rig.txt") && e.contains("camera `left`") && e.contains("zero throughout"), "{e}");
    }

    /// A 3 × 3 block whose determinant is tiny against its rows' lengths is singular, one just
    /// above the bound is a camera.
    #[test]
    fn a_nearly_singular_block_is_refused_and_a_well_conditioned_one_read() {
        let tilted = |e: f64| [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, e, 0.0], [0.0, 1.0, 0.0, 5.0]];
        // det = −e, rows' lengths 1 · √(1 + e²) · 1.
        assert!(camera_from_projection(tilted(1e-13), 8, 8).unwrap_err().contains("singular"));
        assert!(camera_from_projection(tilted(-1e-13), 8, 8).unwrap_err().contains("singular"));
        let e = camera_from_projection(tilted(1e-11), 8, 8);
        assert!(e.as_ref().map_or_else(|e| !e.contains("singular"), |_| true), "{e:?}");
    }

    #[test]
    fn twelve_numbers_on_a_line_or_per_column_are_matrices_row_by_row() {
        let dir = tempfile::tempdir().unwrap();
        let line = write(dir.path(), "p.txt", "1 2 3 4 5 6 7 8 9 10 11 12\n");
        let c = read_projection(&line).unwrap();
        assert_eq!((c[0].name.as_str(), c[0].form), ("p", ProjectionForm::Matrix));
        assert_eq!(c[0].matrix, [[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0], [9.0, 10.0, 11.0, 12.0]]);
        let cols: String = (1..=12).map(|i| format!("{i}\t{}\n", -i)).collect();
        let c = read_projection(&write(dir.path(), "cols.csv", &format!("\"front\"\t\"back\"\n{cols}"))).unwrap();
        assert_eq!(c.iter().map(|c| c.name.as_str()).collect::<Vec<_>>(), ["front", "back"]);
        assert_eq!(c[1].form, ProjectionForm::Matrix);
        assert_eq!(c[1].matrix[2], [-9.0, -10.0, -11.0, -12.0]);
        assert_eq!(c[0].matrix[1], [5.0, 6.0, 7.0, 8.0]);
        // One column without names is named after the file.
        let one: String = (1..=11).map(|i| format!("{i}\n")).collect();
        let c = read_projection(&write(dir.path(), "cam7.dat", &one)).unwrap();
        assert_eq!((c.len(), c[0].name.as_str(), c[0].form), (1, "cam7", ProjectionForm::Dlt));
        assert_eq!(c[0].matrix[2], [9.0, 10.0, 11.0, 1.0]);
    }

    #[test]
    fn names_are_refused_where_they_cannot_name_columns() {
        let dir = tempfile::tempdir().unwrap();
        let e = read_projection(&write(dir.path(), "m.txt", "left\n1 0 0 4\n0 1 0 5\n0 0 1 6\n")).unwrap_err();
        assert!(e.to_string().contains("its first line holds names (left)"), "{e}");
        let e = read_projection(&write(dir.path(), "l.txt", "left\n1 2 3 4 5 6 7 8 9 10 11\n")).unwrap_err();
        assert!(e.to_string().contains("which only a file of one camera per column has"), "{e}");
        let e = read_projection(&write(dir.path(), "s.csv", &format!("a/b c\n{}", "1 2\n".repeat(11)))).unwrap_err();
        assert!(e.to_string().contains("`a/b` in its first line is not a camera name"), "{e}");
        let e = read_projection(&write(dir.path(), "q.csv", &format!("\"\" c\n{}", "1 2\n".repeat(11)))).unwrap_err();
        assert!(e.to_string().contains("`` in its first line is not a camera name"), "{e}");
    }
}
