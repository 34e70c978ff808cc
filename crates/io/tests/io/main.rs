//! Integration tests of the readers and writers, one module per format or theme, built as one test
//! binary. The video tests that change environment variables and the counting-allocator test stay
//! binaries of their own.

mod calib;
mod damaged_files;
mod davis;
mod fuzz;
mod metashape;
mod projection_scale;
mod raw_pair;
mod recording;
mod transforms;
mod video;
