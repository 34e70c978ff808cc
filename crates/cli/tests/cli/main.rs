//! End-to-end tests of the `fluidnerf` command, one module per command or theme, built as one
//! test binary (one link instead of one per file, and one pool of test threads for all).

mod common;

mod compare;
mod demo;
mod eval;
mod export;
mod import;
mod info;
mod malformed;
mod output_folders;
mod real_like;
mod reconstruct_classical;
mod reconstruct_neural;
mod reconstruct_split;
mod reconstruct_temporal;
mod render;
mod rerun;
mod study;
mod synth;
