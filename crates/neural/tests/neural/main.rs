//! Integration tests of the neural fields and their training engine, one module per theme, built
//! as one test binary.

mod common;

mod damaged_files;
mod engine_cpu;
mod engine_determinism;
mod engine_equivalence;
mod engine_gradients;
mod engine_optim;
mod masks_gains;
mod method_ball;
mod prior;
mod start;
mod temporal_blob;
mod uniform_start;
mod world_field;
