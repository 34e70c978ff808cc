//! Metashape camera exports ("Agisoft XML") written from known cameras, for tests of
//! `fluidnerf_io::calib::read_metashape` and of `fluidnerf import --metashape`.

use fluidnerf_core::glam::{DMat3, DVec3};
use fluidnerf_core::Camera;

/// A chunk's transform, `x_world = scale · rotation x_chunk + translation`.
pub struct ChunkTransform {
    pub rotation: DMat3,
    pub translation: DVec3,
    pub scale: f64,
}

fn row_major(m: DMat3) -> String {
    let r = m.transpose().to_cols_array();
    r.iter().map(|v| format!("{v:e}")).collect::<Vec<_>>().join(" ")
}

/// The `<calibration>` terms of `cam` in Metashape's definitions, independent of the reader: the
/// principal point as an offset from the image centre with pixel centres at +0.5, `b1 = fx − fy`,
/// `b2 = skew`, and Metashape's `P1` (the factor of `r² + 2x²` in x, OpenCV's `p2`) and `P2`.
pub fn calibration_terms(cam: &Camera) -> String {
    let k = &cam.intrinsics;
    let d = &cam.distortion;
    let cx = k.cx + 0.5 - f64::from(k.width) / 2.0;
    let cy = k.cy + 0.5 - f64::from(k.height) / 2.0;
    format!(
        "<f>{:e}</f><cx>{cx:e}</cx><cy>{cy:e}</cy><b1>{:e}</b1><b2>{:e}</b2><k1>{:e}</k1><k2>{:e}</k2><k3>{:e}</k3>\
         <p1>{:e}</p1><p2>{:e}</p2>",
        k.fy,
        k.fx - k.fy,
        k.skew,
        d.k1,
        d.k2,
        d.k3,
        d.p2,
        d.p1
    )
}

/// A Metashape export of `cameras` (one sensor each, labelled by name), their transforms in the
/// chunk's internal frame below `chunk` (or in the world, without one).
pub fn metashape_xml(cameras: &[(String, Camera)], chunk: Option<&ChunkTransform>) -> String {
    let mut s = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<document version=\"1.5.0\">\n");
    s += "  <chunk label=\"Chunk 1\" enabled=\"true\">\n    <sensors next_id=\"9\">\n";
    for (i, (name, cam)) in cameras.iter().enumerate() {
        let k = &cam.intrinsics;
        s += &format!(
            "      <sensor id=\"{i}\" label=\"{name} lens\" type=\"frame\">\n        <resolution width=\"{w}\" \
             height=\"{h}\"/>\n        <property name=\"layer_index\" value=\"0\"/>\n        <calibration \
             type=\"frame\" class=\"adjusted\">\n          <resolution width=\"{w}\" height=\"{h}\"/>\n          \
             {}\n        </calibration>\n      </sensor>\n",
            calibration_terms(cam),
            w = k.width,
            h = k.height
        );
    }
    s += "    </sensors>\n    <cameras next_id=\"9\" next_group_id=\"0\">\n";
    for (i, (name, cam)) in cameras.iter().enumerate() {
        // chunk_from_camera = chunk_from_world · world_from_camera, the scale moving the centre only.
        let (r, c) = match chunk {
            Some(t) => (
                t.rotation.transpose() * cam.world_from_camera.matrix3,
                t.rotation.transpose() * (cam.centre() - t.translation) / t.scale,
            ),
            None => (cam.world_from_camera.matrix3, cam.centre()),
        };
        let m = r.transpose().to_cols_array();
        let transform = format!(
            "{:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e} {:e} 0 0 0 1",
            m[0], m[1], m[2], c.x, m[3], m[4], m[5], c.y, m[6], m[7], m[8], c.z
        );
        s += &format!(
            "      <camera id=\"{i}\" sensor_id=\"{i}\" label=\"{name}\">\n        <transform>{transform}</transform>\n        \
             <orientation>1</orientation>\n      </camera>\n"
        );
    }
    s += "    </cameras>\n";
    if let Some(t) = chunk {
        s += &format!(
            "    <transform>\n      <rotation locked=\"false\">{}</rotation>\n      <translation locked=\"false\">{:e} \
             {:e} {:e}</translation>\n      <scale locked=\"true\">{:e}</scale>\n    </transform>\n",
            row_major(t.rotation),
            t.translation.x,
            t.translation.y,
            t.translation.z,
            t.scale
        );
    }
    s += "  </chunk>\n</document>\n";
    s
}
