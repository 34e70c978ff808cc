//! Subcommands. Each module holds a clap `Args` struct and a `run` function.

use std::process::ExitCode;

use clap::Subcommand;

pub mod compare;
pub mod demo;
pub mod eval;
pub mod export;
pub mod import;
pub mod info;
pub mod reconstruct;
pub mod render;
mod scene_subset;
pub mod study;
pub mod synth;

/// The subcommands of `fluidnerf`. Each one's help text is the doc comment of its `Args`.
#[derive(Subcommand)]
pub enum Command {
    Demo(demo::Args),
    Info(info::Args),
    Import(import::Args),
    Reconstruct(reconstruct::Args),
    Eval(eval::Args),
    Compare(compare::Args),
    Export(export::Args),
    Render(render::Args),
    Study(study::Args),
    Synth(synth::Args),
}

/// Runs a parsed subcommand; the exit code is 0, or 130 for a run stopped by Ctrl-C after
/// writing its results.
pub fn run(command: Command) -> anyhow::Result<ExitCode> {
    let done = |r: anyhow::Result<()>| r.map(|()| ExitCode::SUCCESS);
    match command {
        Command::Demo(args) => match demo::run(args) {
            Err(e) if e.downcast_ref::<demo::Interrupted>().is_some() => {
                #[allow(clippy::print_stderr)]
                {
                    eprintln!("{e}");
                }
                Ok(ExitCode::from(130))
            }
            r => done(r),
        },
        Command::Info(args) => done(info::run(args)),
        Command::Import(args) => done(import::run(args)),
        Command::Reconstruct(args) => reconstruct::run(args),
        Command::Eval(args) => done(eval::run(args)),
        Command::Compare(args) => done(compare::run(args)),
        Command::Export(args) => done(export::run(args)),
        Command::Render(args) => done(render::run(args)),
        Command::Study(args) => study::run(args),
        Command::Synth(args) => match synth::run(args) {
            // Stopped by Ctrl-C, as a stopped reconstruction is: its own status, not an error.
            Err(e) if matches!(e.downcast_ref(), Some(fluidnerf_synth::SynthError::Cancelled)) => {
                log::warn!("synth stopped by Ctrl-C; nothing was written");
                Ok(ExitCode::from(130))
            }
            r => done(r),
        },
    }
}

/// The scene a command reads: `--scene` when given, else the scene a run folder's
/// `config.json` records (its path as the run was given it, made absolute). A volume file
/// records no scene, nor does a run folder without a configuration.
#[allow(clippy::print_stdout)]
pub(crate) fn scene_or_recorded(
    given: Option<&std::path::Path>,
    recon: &[std::path::PathBuf],
) -> anyhow::Result<std::path::PathBuf> {
    use anyhow::bail;
    if let Some(scene) = given {
        return Ok(scene.to_path_buf());
    }
    let [dir] = recon else {
        // Run folders do record their scenes: what is wrong is that there are several.
        if let Some(run) = recon.iter().find(|p| p.is_dir()) {
            bail!("{}: give one run folder, or volume files (with --scene)", run.display());
        }
        bail!("give the scene with --scene: {} volumes record no scene", recon.len());
    };
    if !dir.exists() {
        // Told first: that it records no scene would send the user looking for one.
        bail!("{}: no such file or directory", dir.display());
    }
    if !dir.is_dir() {
        bail!("give the scene with --scene: the volume file {} records no scene", dir.display());
    }
    let config = dir.join("config.json");
    let Some(recorded) = recorded_scene(dir)? else {
        bail!("give the scene with --scene: {} holds no config.json that would name its scene", dir.display());
    };
    if !recorded.exists() {
        bail!(
            "{} names the scene {}, which is not there; give the scene with --scene",
            config.display(),
            recorded.display()
        );
    }
    println!("scene {} (recorded in {})", recorded.display(), config.display());
    Ok(recorded)
}

/// The scene a run folder's `config.json` records; None when `recon` is not a run folder with
/// one.
pub(crate) fn recorded_scene(recon: &std::path::Path) -> anyhow::Result<Option<std::path::PathBuf>> {
    use anyhow::Context;
    // A run a killed --force left aside is put back first, as every reader of the folder does:
    // read before, its missing config.json said the folder named no scene.
    if recon.is_dir() {
        fluidnerf_pipeline::rundir::RunDir::recover_replaced(recon);
    }
    let config = recon.join("config.json");
    if !(recon.is_dir() && config.is_file()) {
        return Ok(None);
    }
    let scene = fluidnerf_pipeline::RunConfig::read(&config)
        .with_context(|| format!("reading {} for the run's scene", config.display()))?
        .scene;
    Ok(Some(scene))
}

/// The folder of the scene at `path` (the folder or its `transforms.json`), resolved to one
/// spelling; None when it does not exist ([`fluidnerf_pipeline::load::scene_folder`]).
pub(crate) fn scene_folder(path: &std::path::Path) -> Option<std::path::PathBuf> {
    fluidnerf_pipeline::load::scene_folder(path)
}

/// Warns that `what` (a run, a volume file, the truth) fills `aabb`, not the scene's box
/// ([`fluidnerf_pipeline::load::other_box_note`]; `consequence` says what follows).
pub(crate) fn warn_of_other_box(
    what: &str,
    aabb: &fluidnerf_core::Aabb,
    scene: &fluidnerf_core::Scene,
    consequence: &str,
) {
    if let Some(note) = fluidnerf_pipeline::load::other_box_note(what, aabb, scene, consequence) {
        log::warn!("{note}");
    }
}

/// Warns that the run in `dir`, made from the scene `made_from`, is used with the scene `given`
/// ([`fluidnerf_pipeline::load::other_scene_note`]; `how` says how).
pub(crate) fn warn_of_other_scene(
    dir: &std::path::Path,
    made_from: &std::path::Path,
    given: &std::path::Path,
    how: &str,
) {
    if let Some(note) = fluidnerf_pipeline::load::other_scene_note(dir, made_from, given, how) {
        log::warn!("{note}");
    }
}

/// Parses `--seed`: a whole number from 0 to 2^64 − 1. clap's own parser for a u64 answered
/// `-1` with "unexpected argument" (taking it for an option) or "invalid digit found in
/// string", neither of which says what a seed may be.
pub(crate) fn parse_seed(s: &str) -> Result<u64, String> {
    s.trim().parse().map_err(|_| format!("a seed is a whole number from 0 to 2^64 - 1 ({}), got `{s}`", u64::MAX))
}

/// Parses an iteration cap (`--max-iterations`): 1 to [`fluidnerf_core::MAX_ITERATIONS`]. A
/// cap of 2^64 − 1 overflowed the progress total of a run of several windows.
/// Iteration cap of the runs of a comparison (`study`, `demo`) without `--max-iterations`.
/// Under held-out stopping and the budget rule, the rule and the same time budget end every
/// method's run: a method's own cap would stop some methods while they still improve
/// (`docs/claims.md` has an example), so the cap is set far above what any method does in a
/// budget. Under the methods' own rules each keeps its own cap, which is part of that rule.
pub(crate) const UNCAPPED: usize = 1_000_000;

/// The cap [`UNCAPPED`] describes: None (each method's own) under `--stop own`.
pub(crate) fn comparison_cap(stop: reconstruct::StopArg) -> Option<usize> {
    match stop {
        reconstruct::StopArg::Own => None,
        _ => Some(UNCAPPED),
    }
}

pub(crate) fn parse_max_iterations(s: &str) -> Result<usize, String> {
    let max = fluidnerf_core::MAX_ITERATIONS;
    match s.trim().parse::<u64>() {
        Ok(n) if (1..=max as u64).contains(&n) => Ok(n as usize),
        _ => Err(format!("an iteration cap is a whole number from 1 to {max}, got `{s}`")),
    }
}

/// The synthetic scene preset `name` given as `option` of `command`, which compares static
/// reconstructions of one instant: refused, before anything is made, when it is unknown or
/// holds several instants, which every static method would mix into one field (and score
/// against the first instant's truth only).
pub(crate) fn static_preset(option: &str, name: &str, command: &str) -> anyhow::Result<fluidnerf_synth::SynthSettings> {
    let settings = fluidnerf_synth::preset::preset(name)
        .map_err(|e| anyhow::anyhow!("{option}: {e} (fluidnerf synth --list-presets)"))?;
    if settings.times.len() > 1 {
        anyhow::bail!(
            "{option}: {name} holds {} instants; {command} compares static reconstructions of one instant: choose a \
             static preset (fluidnerf synth --list-presets)",
            settings.times.len()
        );
    }
    Ok(settings)
}

/// Refuses a value given twice to the list option `option`: the repeat would run the same work
/// twice, write the same file twice or print the same row twice.
pub(crate) fn given_once<T: PartialEq + std::fmt::Display>(option: &str, values: &[T]) -> anyhow::Result<()> {
    match values.iter().enumerate().find(|&(i, v)| values[..i].contains(v)) {
        Some((_, v)) => anyhow::bail!("{option}: {v} is given twice; give each value once"),
        None => Ok(()),
    }
}

/// Refuses, before any work, a path given as `what` (an option or argument) that the record
/// file `record` (JSON text) must hold but that is not valid UTF-8: serialising it failed only
/// after the results were written, with an error that named neither path nor option.
pub(crate) fn recordable<'a>(
    record: &str,
    paths: impl IntoIterator<Item = (&'a str, &'a std::path::Path)>,
) -> anyhow::Result<()> {
    for (what, path) in paths {
        if path.to_str().is_none() {
            anyhow::bail!(
                "{what} {}: the path is not valid UTF-8, so {record} (JSON text) cannot record it; rename it",
                path.display()
            );
        }
    }
    Ok(())
}

/// Refuses work whose largest buffers (`bytes`, estimated) exceed the memory available now,
/// before anything is computed or written: an allocation that fails aborts the program.
pub(crate) fn check_memory(what: impl FnOnce() -> String, bytes: u64) -> anyhow::Result<()> {
    match fluidnerf_pipeline::available_memory() {
        Some(available) if bytes > available => anyhow::bail!(
            "{} needs about {} but only {} are available",
            what(),
            fluidnerf_pipeline::bytes(bytes),
            fluidnerf_pipeline::bytes(available)
        ),
        _ => Ok(()),
    }
}

/// Runs one subcommand line in-process, exactly as a user would type it (without the program
/// name): the demo and studies synthesise their scenes and score their runs this way. The exit
/// code is the command's: 130 for one stopped by Ctrl-C (which returns no error).
pub(crate) fn run_line(line: &[String]) -> anyhow::Result<ExitCode> {
    use clap::Parser;
    let mut argv = vec!["fluidnerf".to_string()];
    argv.extend(line.iter().cloned());
    let cli = crate::Cli::try_parse_from(&argv).map_err(|e| anyhow::anyhow!("{e}"))?;
    run(cli.command)
}

/// Creates a command's output folder `out` (and its parents), or refuses it by what is in the
/// way: an existing file there, or a file where one of its parents should be.
pub(crate) fn create_output_folder(out: &std::path::Path) -> anyhow::Result<()> {
    fluidnerf_pipeline::rundir::refuse_non_folder(out)?;
    std::fs::create_dir_all(out).map_err(|e| anyhow::anyhow!("{}: cannot create the output folder: {e}", out.display()))
}

/// Refuses, before any work, an output folder `out` that takes no new file: it, or the nearest
/// folder above it that exists, is probed as [`fluidnerf_io::check_writable`] does. A read-only
/// folder failed only once the results were ready (a long export or render done for nothing).
pub(crate) fn refuse_unwritable_output(out: &std::path::Path) -> anyhow::Result<()> {
    let existing = out.ancestors().find(|a| a.as_os_str().is_empty() || a.exists()).unwrap_or(out);
    let folder = if existing.as_os_str().is_empty() { std::path::Path::new(".") } else { existing };
    // A file in the way is refused where the folder is made, by what it is.
    if !folder.is_dir() {
        return Ok(());
    }
    fluidnerf_io::check_writable(&folder.join("out"))
        .map_err(|e| anyhow::anyhow!("{}: cannot write into the output folder: {e}", out.display()))
}
