//! Metashape camera exports: a hand-written file projects as Metashape's camera model says
//! (worked by hand, with its own order of the tangential terms), files written from known
//! cameras read as the OpenCV files of the same cameras, and malformed files are refused naming
//! the file and the camera or sensor.

#[path = "../common/metashape.rs"]
mod metashape_xml;

use fluidnerf_core::glam::{DMat3, DVec2, DVec3};
use fluidnerf_core::{Camera, Distortion, Intrinsics};
use fluidnerf_io::calib::{read_metashape, read_opencv, write_opencv};
use metashape_xml::{metashape_xml, ChunkTransform};

/// A two-camera export with distortion, affinity and skew, a chunk transform (rotation about
/// z by 30°, a translation and scale 2) and a camera in a group; a third camera not aligned.
const HAND_WRITTEN: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<document version="2.0.0">
  <chunk label="Rig" enabled="true">
    <sensors next_id="1">
      <sensor id="0" label="C1 (16mm)" type="frame">
        <resolution width="640" height="480"/>
        <property name="pixel_width" value="0.0058"/>
        <calibration type="frame" class="initial">
          <resolution width="640" height="480"/>
          <f>900</f>
        </calibration>
        <calibration type="frame" class="adjusted">
          <resolution width="640" height="480"/>
          <f>1000.5</f>
          <cx>12.25</cx>
          <cy>-7.5</cy>
          <b1>3.5</b1>
          <b2>-1.25</b2>
          <k1>-0.12</k1>
          <k2>0.045</k2>
          <k3>-0.011</k3>
          <p1>0.0021</p1>
          <p2>-0.0013</p2>
        </calibration>
        <covariance><params>f cx cy</params><coeffs>1 0 0 0 1 0 0 0 1</coeffs></covariance>
      </sensor>
    </sensors>
    <cameras next_id="3" next_group_id="1">
      <camera id="0" sensor_id="0" label="left">
        <transform>1 0 0 -5 0 1 0 0.5 0 0 1 -40 0 0 0 1</transform>
        <orientation>1</orientation>
      </camera>
      <group id="0" label="Station" type="folder">
        <camera id="1" sensor_id="0" label="right">
          <transform>0.8 0 -0.6 30 0 1 0 -1 0.6 0 0.8 -35 0 0 0 1</transform>
        </camera>
        <camera id="2" sensor_id="0" label="spare">
          <orientation>1</orientation>
        </camera>
      </group>
    </cameras>
    <transform>
      <rotation locked="false">0.8660254037844387 -0.5 0 0.5 0.8660254037844387 0 0 0 1</rotation>
      <translation locked="false">10 -20 5</translation>
      <scale locked="true">2</scale>
    </transform>
  </chunk>
</document>
"#;

/// Metashape's projection of the hand-written file's sensor (manual, appendix "Camera models",
/// frame cameras), in Metashape's image coordinates (top-left pixel centred at (0.5, 0.5)), of
/// a point in the camera's frame.
fn metashape_projection(p: DVec3) -> DVec2 {
    let (w, h, f, cx, cy, b1, b2) = (640.0, 480.0, 1000.5, 12.25, -7.5, 3.5, -1.25);
    let (k1, k2, k3, p1, p2) = (-0.12, 0.045, -0.011, 0.0021, -0.0013);
    let (x, y) = (p.x / p.z, p.y / p.z);
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    let xd = x * radial + p1 * (r2 + 2.0 * x * x) + 2.0 * p2 * x * y;
    let yd = y * radial + p2 * (r2 + 2.0 * y * y) + 2.0 * p1 * x * y;
    DVec2::new(w * 0.5 + cx + xd * f + xd * b1 + yd * b2, h * 0.5 + cy + yd * f)
}

/// Points around the two cameras' common view, in the world.
fn world_points(cams: &[(String, Camera)]) -> Vec<DVec3> {
    let mut out = Vec::new();
    for (_, c) in cams {
        for (i, j) in [(-0.3, -0.2), (0.0, 0.0), (0.25, -0.1), (0.1, 0.3), (-0.2, 0.25)] {
            let d = c.world_from_camera.matrix3 * DVec3::new(i, j, 1.0);
            out.push(c.centre() + d * 60.0);
        }
    }
    out
}

#[test]
fn a_hand_written_export_projects_as_metashape_documents() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("cameras.xml");
    std::fs::write(&path, HAND_WRITTEN).expect("writes");
    let read = read_metashape(&path).expect("reads");
    assert_eq!(read.unaligned, ["spare"]);
    assert!(read.disabled.is_empty());
    assert_eq!(read.units, Some("m"), "a chunk transform gives the chunk's (metric) coordinates");
    let names: Vec<&str> = read.cameras.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["left", "right"], "in the file's order, through groups");
    let k = read.cameras[0].1.intrinsics;
    assert_eq!(k.fy, 1000.5, "the adjusted calibration wins over the initial one");
    assert_eq!((k.fx, k.skew), (1004.0, -1.25), "fx = f + b1, skew = b2");
    assert_eq!((k.cx, k.cy), (331.75, 232.0), "offsets from the centre, pixel centres at +0.5");
    let d = read.cameras[0].1.distortion;
    assert_eq!((d.p1, d.p2), (-0.0013, 0.0021), "Metashape's P1 is OpenCV's p2");

    let rotation = DMat3::from_rotation_z(30f64.to_radians());
    let (translation, scale) = (DVec3::new(10.0, -20.0, 5.0), 2.0);
    let chunk_poses = [
        (DMat3::IDENTITY, DVec3::new(-5.0, 0.5, -40.0)),
        (DMat3::from_cols_array(&[0.8, 0.0, 0.6, 0.0, 1.0, 0.0, -0.6, 0.0, 0.8]), DVec3::new(30.0, -1.0, -35.0)),
    ];
    let mut checked = 0;
    for ((name, cam), (r, t)) in read.cameras.iter().zip(chunk_poses) {
        for p in world_points(&read.cameras) {
            // World → chunk (x = Rᵀ(X − t) / s) → camera (Rᵢᵀ(x − tᵢ)), each by hand.
            let in_chunk = rotation.transpose() * (p - translation) / scale;
            let in_camera = r.transpose() * (in_chunk - t);
            let Some(ours) = cam.project(p) else { continue };
            let theirs = metashape_projection(in_camera) - DVec2::splat(0.5);
            assert!((ours - theirs).length() < 1e-9 * theirs.length(), "{name}: {p}: {ours} vs {theirs}");
            checked += 1;
        }
    }
    assert!(checked >= 15, "only {checked} points in front of the cameras");
}

/// Three cameras on a ring, with every term the two formats share.
fn rig() -> Vec<(String, Camera)> {
    let k = Intrinsics { width: 64, height: 48, fx: 82.5, fy: 80.0, cx: 30.25, cy: 24.5, skew: 0.75 };
    (0..3)
        .map(|c| {
            let a = c as f64 / 3.0 * std::f64::consts::TAU;
            let centre = DVec3::new(90.0 * a.cos(), 90.0 * a.sin(), 20.0 + 5.0 * c as f64);
            let mut cam = Camera::look_at(k, centre, DVec3::new(1.0, -2.0, 0.5), DVec3::Z);
            cam.distortion = Distortion {
                k1: -0.08 + 0.02 * c as f64,
                k2: 0.03,
                k3: -0.004,
                p1: 2e-3,
                p2: -7e-4,
                ..Default::default()
            };
            (format!("cam{c}"), cam)
        })
        .collect()
}

#[test]
fn an_export_reads_as_the_opencv_calibration_of_the_same_cameras() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cams = rig();
    let opencv = dir.path().join("rig.yml");
    write_opencv(&opencv, &cams).expect("writes");
    let by_opencv = read_opencv(&opencv).expect("reads");
    let chunk = ChunkTransform {
        rotation: DMat3::from_euler(fluidnerf_core::glam::EulerRot::ZYX, 0.7, -0.3, 1.9),
        translation: DVec3::new(-120.0, 45.0, 3.5),
        scale: 0.025,
    };
    for (transform, units) in [(Some(&chunk), Some("m")), (None, None)] {
        let path = dir.path().join("cameras.xml");
        std::fs::write(&path, metashape_xml(&cams, transform)).expect("writes");
        let read = read_metashape(&path).expect("reads");
        assert_eq!(read.units, units);
        assert_eq!(read.cameras.len(), 3);
        let mut checked = 0;
        for ((name, ours), (other, theirs)) in read.cameras.iter().zip(&by_opencv) {
            assert_eq!(name, other);
            for p in world_points(&cams) {
                let (Some(a), Some(b)) = (ours.project(p), theirs.project(p)) else { continue };
                assert!((a - b).length() <= 1e-6 * b.length(), "{name}: {p}: {a} vs {b}");
                checked += 1;
            }
        }
        assert!(checked >= 15, "only {checked} points in front of the cameras");
    }
}

/// Writes `text` as `DIR/bad.xml` and returns the error of reading it.
fn refused(dir: &std::path::Path, text: &str) -> String {
    let path = dir.join("bad.xml");
    std::fs::write(&path, text).expect("writes");
    let e = read_metashape(&path).expect_err("refused").to_string();
    assert!(e.contains("bad.xml"), "{e}");
    e
}

#[test]
fn malformed_exports_are_refused_naming_the_camera_or_sensor() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dir = dir.path();
    let base = HAND_WRITTEN;
    let cases: Vec<(String, &[&str])> = vec![
        (
            base.replace("sensor_id=\"0\" label=\"right\"", "sensor_id=\"7\" label=\"right\""),
            &["camera `right`", "sensor 7", "does not define"],
        ),
        (base.replace("<f>1000.5</f>", "<f>1000,5</f>"), &["sensor 0 (`C1 (16mm)`)", "`<f>`", "`1000,5`"]),
        (base.replace("<f>1000.5</f>", ""), &["sensor 0", "no `<f>`"]),
        (base.replace("<k2>0.045</k2>", "<k2>nan</k2>"), &["sensor 0", "`<k2>`", "not a finite number"]),
        (base.replace("0 0 1 -40 0 0 0 1", "0 0 1 -40 0 0 0"), &["camera `left`", "`<transform>`", "15 number(s)"]),
        (base.replace("0.8 0 -0.6 30", "0.8 0 -0.5 30"), &["camera `right`", "not a rotation"]),
        (base.replace("0 0 1 -40 0 0 0 1", "0 0 1 -40 0 0 1 1"), &["camera `left`", "0 0 0 1"]),
        (base.replace("type=\"frame\">", "type=\"fisheye\">"), &["sensor 0", "`fisheye`", "only `frame`"]),
        (base.replace("<k3>-0.011</k3>", "<k3>-0.011</k3><k4>0.002</k4>"), &["sensor 0", "`<k4>`"]),
        (base.replace("<p2>-0.0013</p2>", "<p2>-0.0013</p2><p3>0.1</p3>"), &["sensor 0", "`<p3>`"]),
        (base.replace("<f>1000.5</f>", "<fx>1000.5</fx><fy>1000</fy>"), &["sensor 0", "`<fx>`", "PhotoScan 1.2"]),
        (
            base.replace("<scale locked=\"true\">2</scale>", "<scale>-2</scale>"),
            &["chunk's `<transform>`", "`<scale>`"],
        ),
        (
            base.replace("<scale locked=\"true\">2</scale>", "<scale>1e-300</scale>"),
            &["chunk's `<transform>`", "`<scale>` is 1e-300", "between 1e-100 and 1e100"],
        ),
        (
            base.replace("0.5 0.8660254037844387 0", "0.6 0.8660254037844387 0"),
            &["chunk's `<transform>`", "not a rotation"],
        ),
        (base.replace("label=\"right\"", "label=\"left\""), &["camera `left`", "listed twice"]),
        (
            base.replace("<sensors next_id=\"1\">", "<sensors next_id=\"1\"></sensors><x>")
                .replace("</sensors>\n    <cameras", "</x>\n    <cameras"),
            &["camera `left`", "sensors: none"],
        ),
        (base.replace("<document", "<doc").replace("</document>", "</doc>"), &["`<doc>`", "`<document>`"]),
        (base.replace("</chunk>", "</chunk><chunk/>"), &["2 chunks"]),
        (
            base.replace("<cameras next_id", "<cameras><x/></cameras><c next_id")
                .replace("</cameras>\n    <transform>", "</c>\n    <transform>"),
            &["lists no camera"],
        ),
        (base.replace("</document>", ""), &["malformed XML"]),
        (base.replace("label=\"left\"", "label=\"left\" component_id=\"3\""), &["camera `left`", "component 3"]),
        (
            base.replace(
                "<resolution width=\"640\" height=\"480\"/>\n          <f>1000.5",
                "<resolution width=\"320\" height=\"240\"/>\n          <f>1000.5",
            ),
            &["sensor 0", "320x240", "640x480"],
        ),
    ];
    for (text, needles) in cases {
        assert_ne!(text, base, "the case changes the file: {needles:?}");
        let e = refused(dir, &text);
        for n in needles {
            assert!(e.contains(n), "{e}\nshould name {n}");
        }
    }
    // An unsupported sensor that no camera uses is not read.
    let unused = base.replace(
        "    </sensors>",
        "      <sensor id=\"5\" label=\"pano\" type=\"spherical\"><resolution width=\"8\" height=\"4\"/></sensor>\n    </sensors>",
    );
    std::fs::write(dir.join("unused.xml"), unused).expect("writes");
    assert!(read_metashape(&dir.join("unused.xml")).is_ok());
}

#[test]
fn disabled_cameras_components_and_initial_calibrations() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("cameras.xml");
    // Only an initial calibration (a fixed, precalibrated lens) and a disabled camera.
    let text = HAND_WRITTEN
        .replace("class=\"adjusted\"", "class=\"other\"")
        .replace("<calibration type=\"frame\" class=\"other\">", "<calibration type=\"frame\" class=\"x\">")
        .replace("label=\"right\"", "label=\"right\" enabled=\"false\"");
    std::fs::write(&path, &text).expect("writes");
    let read = read_metashape(&path).expect("reads");
    assert_eq!(read.cameras.len(), 1);
    assert_eq!(read.cameras[0].1.intrinsics.fx, 900.0, "the initial calibration");
    assert_eq!(read.disabled, ["right"]);
    assert_eq!(read.unaligned, ["spare"]);

    // Metashape 2 writes the transform per component: the same cameras, the same poses.
    let chunk = read_metashape(&{
        std::fs::write(&path, HAND_WRITTEN).expect("writes");
        path.clone()
    })
    .expect("reads");
    let start = HAND_WRITTEN.find("    <transform>\n      <rotation").expect("chunk transform");
    let end = HAND_WRITTEN.find("  </chunk>").expect("chunk end");
    let transform = &HAND_WRITTEN[start..end];
    let components = format!(
        "    <components next_id=\"1\" active_id=\"0\">\n      <component id=\"0\" label=\"Component 1\">\n{transform}      </component>\n    </components>\n"
    );
    let text = HAND_WRITTEN
        .replace(transform, "")
        .replace("    <cameras next_id", &format!("{components}    <cameras next_id"));
    let text = text
        .replace("label=\"left\"", "label=\"left\" component_id=\"0\"")
        .replace("label=\"right\"", "label=\"right\" component_id=\"0\"");
    std::fs::write(&path, &text).expect("writes");
    let read = read_metashape(&path).expect("reads");
    assert_eq!(read.units, Some("m"));
    for ((_, a), (_, b)) in read.cameras.iter().zip(&chunk.cameras) {
        assert!(
            (a.centre() - b.centre()).length() < 1e-12 && a.world_from_camera.abs_diff_eq(b.world_from_camera, 1e-12)
        );
    }
    // A component's transform other than the chunk's leaves the frame unclear.
    let both =
        text.replace("  </chunk>", &format!("{}  </chunk>", transform.replace("<scale locked=\"true\">2", "<scale>3")));
    let e = refused(dir.path(), &both);
    assert!(e.contains("camera `left`") && e.contains("differs from the chunk's"), "{e}");
    // Only disabled and unaligned cameras: nothing to import, each one named.
    let none = HAND_WRITTEN
        .replace("label=\"left\"", "label=\"left\" enabled=\"0\"")
        .replace("label=\"right\"", "label=\"right\" enabled=\"false\"");
    let e = refused(dir.path(), &none);
    assert!(e.contains("not aligned: spare") && e.contains("disabled: left, right"), "{e}");
}

/// The hand-written file with its chunk transform replaced by `transform` (none when empty).
fn with_chunk_transform(transform: &str) -> String {
    let start = HAND_WRITTEN.find("    <transform>\n      <rotation").expect("chunk transform");
    let end = HAND_WRITTEN.find("  </chunk>").expect("chunk end");
    format!("{}{transform}{}", &HAND_WRITTEN[..start], &HAND_WRITTEN[end..])
}

fn read_text(dir: &std::path::Path, text: &str) -> fluidnerf_io::calib::MetashapeCameras {
    let path = dir.join("cameras.xml");
    std::fs::write(&path, text).expect("writes");
    read_metashape(&path).expect("reads")
}

/// A chunk transform of a translation alone, a scale alone or a rotation alone moves the
/// camera `left` (at (−5, 0.5, −40) in the chunk) by that part alone, the others being the
/// identity.
#[test]
fn each_part_of_a_chunk_transform_applies_on_its_own() {
    let dir = tempfile::tempdir().expect("tempdir");
    let left = DVec3::new(-5.0, 0.5, -40.0);
    let turn = DMat3::from_rotation_z(90f64.to_radians());
    let cases = [
        ("<translation>1 2 3</translation>", left + DVec3::new(1.0, 2.0, 3.0), DMat3::IDENTITY),
        ("<scale>2</scale>", left * 2.0, DMat3::IDENTITY),
        ("<rotation>0 -1 0 1 0 0 0 0 1</rotation>", turn * left, turn),
    ];
    for (part, centre, rotation) in cases {
        let read = read_text(dir.path(), &with_chunk_transform(&format!("    <transform>{part}</transform>\n")));
        let cam = &read.cameras[0].1;
        assert!((cam.centre() - centre).length() < 1e-9, "{part}: {}", cam.centre());
        assert!((cam.world_from_camera.matrix3 - rotation).abs_diff_eq(DMat3::ZERO, 1e-12), "{part}");
        assert_eq!(read.units, Some("m"), "{part}");
    }
    let read = read_text(dir.path(), &with_chunk_transform(""));
    assert_eq!((read.cameras[0].1.centre(), read.units), (left, None), "no transform: the internal frame");
}

/// A component and a chunk that give one transform agree; a camera placed by a component's
/// transform beside one placed by none stand in different frames and are refused.
#[test]
fn component_and_chunk_transforms_must_place_every_camera_alike() {
    let dir = tempfile::tempdir().expect("tempdir");
    let start = HAND_WRITTEN.find("    <transform>\n      <rotation").expect("chunk transform");
    let end = HAND_WRITTEN.find("  </chunk>").expect("chunk end");
    let transform = &HAND_WRITTEN[start..end];
    let components =
        format!("    <components>\n      <component id=\"0\">\n{transform}      </component>\n    </components>\n");
    let both = HAND_WRITTEN
        .replace("    <cameras next_id", &format!("{components}    <cameras next_id"))
        .replace("label=\"left\"", "label=\"left\" component_id=\"0\"");
    let chunk = read_text(dir.path(), HAND_WRITTEN);
    let read = read_text(dir.path(), &both);
    assert_eq!(read.cameras.len(), 2);
    for ((_, a), (_, b)) in read.cameras.iter().zip(&chunk.cameras) {
        assert!(a.world_from_camera.abs_diff_eq(b.world_from_camera, 1e-12));
    }
    // Without the chunk's transform, `right` (in no component) stands in the internal frame.
    let mixed = with_chunk_transform("")
        .replace("    <cameras next_id", &format!("{components}    <cameras next_id"))
        .replace("label=\"left\"", "label=\"left\" component_id=\"0\"");
    let e = refused(dir.path(), &mixed);
    assert!(e.contains("camera `left` is placed by") && e.contains("camera `right` by none"), "{e}");
    let mixed = mixed
        .replace("label=\"left\" component_id=\"0\"", "label=\"left\"")
        .replace("label=\"right\"", "label=\"right\" component_id=\"0\"");
    let e = refused(dir.path(), &mixed);
    assert!(e.contains("camera `right` is placed by") && e.contains("camera `left` by none"), "{e}");
}

/// A secondary camera of a multi-camera system without its own transform is refused, and a
/// camera that is its own master is merely not aligned.
#[test]
fn a_secondary_camera_without_a_transform_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let secondary = HAND_WRITTEN.replace("label=\"spare\"", "label=\"spare\" master_id=\"0\"");
    let e = refused(dir.path(), &secondary);
    assert!(e.contains("camera `spare` is a secondary camera") && e.contains("master_id 0"), "{e}");
    let own = HAND_WRITTEN.replace("label=\"spare\"", "label=\"spare\" master_id=\"2\"");
    assert_eq!(read_text(dir.path(), &own).unaligned, ["spare"]);
    // `enabled` in Metashape's spellings, blanks around it allowed; anything else refused.
    let one = HAND_WRITTEN.replace("label=\"right\"", "label=\"right\" enabled=\" 1 \"");
    assert_eq!(read_text(dir.path(), &one).cameras.len(), 2);
    let e = refused(dir.path(), &HAND_WRITTEN.replace("label=\"right\"", "label=\"right\" enabled=\"yes\""));
    assert!(e.contains("camera `right`: `enabled` is `yes`"), "{e}");
}

/// A calibration without its own resolution takes the sensor's; one without a class is used
/// when it is the only one; the image size is nowhere, or a class is given twice, is refused.
#[test]
fn calibrations_take_the_sensors_resolution_and_a_lone_unclassed_one_is_used() {
    let dir = tempfile::tempdir().expect("tempdir");
    let own_resolution =
        "<calibration type=\"frame\" class=\"adjusted\">\n          <resolution width=\"640\" height=\"480\"/>";
    let sensor_only = HAND_WRITTEN.replace(own_resolution, "<calibration type=\"frame\" class=\"adjusted\">");
    let read = read_text(dir.path(), &sensor_only);
    let k = read.cameras[0].1.intrinsics;
    assert_eq!((k.width, k.height, k.cx, k.cy), (640, 480, 331.75, 232.0));
    let initial = "<calibration type=\"frame\" class=\"initial\">\n          <resolution width=\"640\" height=\"480\"/>\n          <f>900</f>\n        </calibration>";
    let unclassed = HAND_WRITTEN.replace(initial, "").replace("class=\"adjusted\"", "");
    assert_eq!(read_text(dir.path(), &unclassed).cameras[0].1.intrinsics.fy, 1000.5);
    let two = HAND_WRITTEN.replace("class=\"initial\"", "class=\"adjusted\"");
    let e = refused(dir.path(), &two);
    assert!(e.contains("sensor 0") && e.contains("two `<calibration class=\"adjusted\">`"), "{e}");
    let nowhere = sensor_only.replace("<resolution width=\"640\" height=\"480\"/>\n        <property", "<property");
    let e = refused(dir.path(), &nowhere);
    assert!(e.contains("no `<resolution>`, here or in the sensor"), "{e}");
    let e = refused(
        dir.path(),
        &HAND_WRITTEN.replace(
            "<resolution width=\"640\" height=\"480\"/>\n        <property",
            "<resolution width=\"0\" height=\"480\"/>\n        <property",
        ),
    );
    assert!(e.contains("`<resolution>` `width` is `0`; expected a positive integer"), "{e}");
}
