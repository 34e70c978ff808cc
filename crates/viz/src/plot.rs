//! Line plots: convergence histories and parameter sweeps.
