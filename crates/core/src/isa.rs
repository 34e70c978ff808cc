//! The instruction sets the vector kernels of every crate are compiled for, chosen at run time.

/// Instruction sets the kernels are compiled for, in increasing order. Each kernel documents
/// what its versions share: most give the same bits on every one (no fused multiply–adds are
/// formed), the footprint forward projection up to the order in which overlapping footprints
/// are summed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Isa {
    /// The x86-64 baseline (SSE2), or portable code elsewhere.
    Baseline,
    /// AVX2: eight f32 lanes per instruction, gathers.
    Avx2,
    /// AVX-512F: sixteen f32 lanes per instruction.
    Avx512,
}

impl Isa {
    /// The widest instruction set this CPU supports (cached by the standard library).
    pub fn detected() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx512f") && has!("avx2") {
                return Isa::Avx512;
            }
            if has!("avx2") {
                return Isa::Avx2;
            }
        }
        Isa::Baseline
    }

    /// Every instruction set this CPU runs, from the baseline up.
    pub fn available() -> Vec<Isa> {
        [Isa::Baseline, Isa::Avx2, Isa::Avx512].into_iter().filter(|&i| i <= Isa::detected()).collect()
    }
}
