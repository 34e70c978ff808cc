//! The `fluidnerf` command-line tool. Each subcommand lives in `commands/`; this file only
//! parses arguments, sets up logging and maps errors to exit codes.

use std::process::ExitCode;

use clap::Parser;

mod commands;
mod interrupt;
mod progress;

/// Tomography of flows: reconstruct the 3D (or 4D) scalar field of glowing smoke, dye or
/// flame from a handful of calibrated camera images.
///
/// A scene is a folder with a nerfstudio-style `transforms.json` (cameras, image paths, the
/// reconstruction box `aabb`) and its images. Start with `fluidnerf demo`, or inspect a scene
/// with `fluidnerf info SCENE`.
#[derive(Parser)]
#[command(name = "fluidnerf", version, about, long_about, max_term_width = 100)]
struct Cli {
    /// More log output (-v: info, -vv: debug). RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// Log only errors and draw no progress bars. A command's results, and the files it wrote,
    /// still print on standard output.
    #[arg(short, long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: commands::Command,
}

fn main() -> ExitCode {
    // Exit quietly when the reader of stdout goes away (`fluidnerf eval … | head`), as Unix
    // tools do, instead of failing on the next print. Files are written atomically, so none is
    // left half-written.
    #[cfg(unix)]
    // SAFETY: restoring a signal's default disposition at start-up, before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    let level = match (cli.quiet, cli.verbose) {
        (true, _) => log::LevelFilter::Error,
        (false, 0) => log::LevelFilter::Warn,
        (false, 1) => log::LevelFilter::Info,
        (false, _) => log::LevelFilter::Debug,
    };
    env_logger::Builder::new()
        .filter_level(level)
        .format_timestamp(None)
        .format_target(false)
        .parse_default_env()
        .init();
    progress::set_quiet(cli.quiet);
    match commands::run(cli.command) {
        Ok(code) => code,
        Err(err) => {
            #[allow(clippy::print_stderr)]
            {
                eprintln!("error: {err:#}");
            }
            ExitCode::from(1)
        }
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    /// Catches clashing option names between the option groups of different methods.
    #[test]
    fn command_line_definition_is_consistent() {
        super::Cli::command().debug_assert();
    }
}
