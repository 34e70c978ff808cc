//! The kinds of folder fluidnerf's commands write, told by the file that marks each: readers
//! name a folder of another kind for what it is, and writers refuse to mix two kinds.

use std::path::Path;

/// The kind of folder a fluidnerf command writes, told by the file that marks it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FolderKind {
    /// A scene: `transforms.json` (written by `synth` and `import`).
    Scene,
    /// A reconstruction run: `config.json` or `report.json` (written by `reconstruct`).
    Run,
    /// An export: `export.json` (written by `export`).
    Export,
    /// Rendered views: `render.json` (written by `render`).
    Render,
    /// A comparison of runs: `compare.json` (written by `compare`).
    Compare,
    /// A study of methods: `study.json` (written by `study`).
    Study,
    /// A demo: `comparison.json` (written by `demo`).
    Demo,
}

impl FolderKind {
    /// What such a folder is, e.g. "a scene folder".
    pub fn name(self) -> &'static str {
        match self {
            FolderKind::Scene => "a scene folder",
            FolderKind::Run => "a reconstruction run folder",
            FolderKind::Export => "an export folder",
            FolderKind::Render => "a folder of rendered views",
            FolderKind::Compare => "a comparison folder",
            FolderKind::Study => "a study folder",
            FolderKind::Demo => "a demo folder",
        }
    }

    /// What such a folder is, with the file that tells, e.g. "a scene folder (it holds
    /// transforms.json)".
    pub fn describe(self) -> &'static str {
        match self {
            FolderKind::Scene => "a scene folder (it holds transforms.json)",
            FolderKind::Run => "a reconstruction run folder (it holds config.json or report.json)",
            FolderKind::Export => "an export folder (it holds export.json)",
            FolderKind::Render => "a folder of rendered views (it holds render.json)",
            FolderKind::Compare => "a comparison folder (it holds compare.json)",
            FolderKind::Study => "a study folder (it holds study.json)",
            FolderKind::Demo => "a demo folder (it holds comparison.json)",
        }
    }
}

/// The kind of fluidnerf folder `dir` is, if any (None also when it does not exist).
pub fn folder_kind(dir: &Path) -> Option<FolderKind> {
    let has = |name: &str| dir.join(name).is_file();
    if has(crate::scene::SCENE_FILE) {
        Some(FolderKind::Scene)
    } else if has("config.json") || has("report.json") {
        Some(FolderKind::Run)
    } else if has("export.json") {
        Some(FolderKind::Export)
    } else if has("render.json") {
        Some(FolderKind::Render)
    } else if has("compare.json") {
        Some(FolderKind::Compare)
    } else if has("study.json") {
        Some(FolderKind::Study)
    } else if has("comparison.json") {
        Some(FolderKind::Demo)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KINDS: [(FolderKind, &str); 8] = [
        (FolderKind::Scene, "transforms.json"),
        (FolderKind::Run, "config.json"),
        (FolderKind::Run, "report.json"),
        (FolderKind::Export, "export.json"),
        (FolderKind::Render, "render.json"),
        (FolderKind::Compare, "compare.json"),
        (FolderKind::Study, "study.json"),
        (FolderKind::Demo, "comparison.json"),
    ];

    /// Each kind is told by its own file, and its description names that file.
    #[test]
    fn each_kind_is_told_by_the_file_that_marks_it() {
        for (kind, file) in KINDS {
            let dir = tempfile::tempdir().expect("tempdir");
            std::fs::write(dir.path().join(file), "{}").expect("write");
            assert_eq!(folder_kind(dir.path()), Some(kind), "{file}");
            assert!(kind.describe().starts_with(kind.name()), "{kind:?}");
            assert!(kind.describe().contains(file), "{kind:?}: {}", kind.describe());
        }
        let names: std::collections::BTreeSet<&str> = KINDS.iter().map(|(k, _)| k.name()).collect();
        assert_eq!(names.len(), 7, "two kinds share a name: {names:?}");
    }

    /// An empty folder, a missing one, and a folder whose marker is a folder are no kind.
    #[test]
    fn a_folder_without_a_marker_file_is_no_kind() {
        let dir = tempfile::tempdir().expect("tempdir");
        assert_eq!(folder_kind(dir.path()), None);
        assert_eq!(folder_kind(&dir.path().join("missing")), None);
        std::fs::create_dir(dir.path().join("transforms.json")).expect("mkdir");
        assert_eq!(folder_kind(dir.path()), None);
    }

    /// A scene's file wins over a run's, and a run's over the later kinds.
    #[test]
    fn the_first_kind_in_order_wins() {
        let dir = tempfile::tempdir().expect("tempdir");
        for (_, file) in KINDS.iter().rev() {
            std::fs::write(dir.path().join(file), "{}").expect("write");
        }
        assert_eq!(folder_kind(dir.path()), Some(FolderKind::Scene));
        std::fs::remove_file(dir.path().join("transforms.json")).expect("remove");
        assert_eq!(folder_kind(dir.path()), Some(FolderKind::Run));
    }
}
