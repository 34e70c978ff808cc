//! Integration tests of the projectors and solvers, one module per theme, built as one test
//! binary.

mod common;

mod projectors;
mod solvers;
mod tikhonov;
