//! FluidNeRF: neural and grid fields, ray sampling, differentiable rendering and training.
