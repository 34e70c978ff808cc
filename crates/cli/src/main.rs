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
    keep_freed_memory();
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

/// Keeps memory that is freed for the process to use again, up to limits, instead of giving it
/// back to the system at once, which glibc does by default when a thread's heap has 128 kB
/// free at its top. Giving it back costs twice over: the pages are faulted in again when the
/// next buffer of that size is made, and while other threads run, each return makes the
/// kernel flush their CPUs' address caches, an interrupt that is slow in a virtual machine.
/// On a render of a trained field that was 88 returns, a quarter more page faults and about a
/// tenth of its time (`docs/performance.md`). Buffers larger than 32 MiB (volumes) are still
/// mapped on their own and returned when freed; the peak use grows by a few MB (3–4 MB on the
/// demo scene's `fast`, ASART and `hybrid` runs).
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes the allocator's thresholds; called before any thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 128 << 20);
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
