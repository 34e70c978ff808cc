//! Classical algebraic tomography: voxel projectors, ART-family solvers, MLEM, TV.
