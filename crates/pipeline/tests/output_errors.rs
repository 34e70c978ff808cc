//! A run whose outputs cannot be written fails, naming the file, instead of reporting success.

use std::ops::ControlFlow;

use fluidnerf_pipeline::{reconstruct, testing, Method, Overwrite, PipelineError, RunConfig, RunDir, RunEvent};

/// `report.html` that cannot be written (here a folder stands in its way; a full disk does the
/// same) was only a warning: the run wrote `report.json`, said it had written `report.html` and
/// exited with success. It fails naming the file, and `report.json`, the completion marker, is
/// not written.
#[test]
fn a_report_html_that_cannot_be_written_fails_the_run() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let scene_dir = tmp.path().join("scene");
    testing::small_scene(&scene_dir).expect("scene");
    let scene = fluidnerf_io::scene::load_scene(&scene_dir).expect("loads");
    let mut config = RunConfig::new(&scene_dir, Method::Asart);
    config.resolution = 8;
    config.stopping.max_iterations = Some(2);
    let out = tmp.path().join("run");
    let dir = RunDir::create(&out, Overwrite::Refuse, Some(&scene.root)).expect("run folder");
    let blocked = out.join("report.html");
    let e = reconstruct(&scene, &config, &dir, |event| {
        if matches!(event, RunEvent::Started { .. }) {
            std::fs::create_dir_all(blocked.join("x")).expect("blocks report.html");
        }
        ControlFlow::Continue(())
    })
    .expect_err("report.html cannot be written");
    assert!(matches!(e, PipelineError::Viz(_)), "{e:?}");
    assert!(e.to_string().contains("report.html"), "{e}");
    assert!(!out.join("report.json").exists(), "the run is not marked finished");
}
