//! Synthetic benchmark generator: phantoms, camera rigs, image formation, noise.
