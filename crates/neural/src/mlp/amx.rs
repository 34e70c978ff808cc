//! The decoder's matrix products on Intel's AMX tiles (Sapphire Rapids onwards), for the
//! bfloat16 passes of [`super::bf16`].
//!
//! `tdpbf16ps` multiplies a tile of 16 rows × 32 bfloat16 by one of 16 pairs of rows × 16
//! columns and adds the products to 16 × 16 f32 sums: 8192 multiply–adds per instruction, where
//! `vdpbf16ps` does 32. The operands are the bf16 passes' own layouts: an input row of `k`
//! bfloat16 is a row of the A tile, and weights packed as `[k'][columns][2]` are the B tile's
//! pairs of rows. Sums are f32, as there; only their order differs.
//!
//! The tiles are configured once per pass ([`configure`]) with one shape per register, so that
//! every layer's products run without another configuration:
//! - `tmm0`–`tmm3`: the sums, 16 rows × 16 f32 (one per block of 16 output columns);
//! - `tmm5` / `tmm4`: 16 input rows × 32 / 16 bfloat16 (a whole step of `k`, or its last half);
//! - `tmm7` / `tmm6`: 16 / 8 pairs of weight rows × 16 columns.
//!
//! Linux grants a process the tiles' 8 KB of state on request ([`ready`] asks once).

use std::arch::asm;
use std::sync::OnceLock;

/// Rows of a tile.
pub(super) const ROWS: usize = 16;

/// Whether this CPU and kernel give the process AMX with bfloat16: the CPUID bits, then the
/// kernel's permission for the tile data (asked once per process).
pub(super) fn ready() -> bool {
    static READY: OnceLock<bool> = OnceLock::new();
    *READY.get_or_init(|| {
        let id = std::arch::x86_64::__cpuid_count(7, 0);
        let (bf16, tile) = (id.edx & (1 << 22) != 0, id.edx & (1 << 24) != 0);
        if !(bf16 && tile && super::bf16::cpu_has_bf16()) {
            return false;
        }
        const ARCH_REQ_XCOMP_PERM: libc::c_long = 0x1023;
        const XFEATURE_XTILEDATA: libc::c_long = 18;
        // SAFETY: arch_prctl with ARCH_REQ_XCOMP_PERM takes two integers and changes only the
        // process's permission to use the tile state.
        let granted = unsafe { libc::syscall(libc::SYS_arch_prctl, ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA) } == 0;
        if !granted {
            log::debug!("AMX: the kernel refused the tile state; the decoder uses AVX-512 BF16");
        }
        granted
    })
}

/// The tile configuration of palette 1 (64 bytes, as `ldtilecfg` reads it).
#[repr(C, align(64))]
struct TileConfig {
    palette: u8,
    start_row: u8,
    reserved: [u8; 14],
    colsb: [u16; 16],
    rows: [u8; 16],
}

/// Configures the tiles as the module describes. Requires [`ready`].
pub(super) unsafe fn configure() {
    let mut c = TileConfig { palette: 1, start_row: 0, reserved: [0; 14], colsb: [0; 16], rows: [0; 16] };
    for t in 0..4 {
        (c.colsb[t], c.rows[t]) = (64, 16);
    }
    (c.colsb[4], c.rows[4]) = (32, 16);
    (c.colsb[5], c.rows[5]) = (64, 16);
    (c.colsb[6], c.rows[6]) = (64, 8);
    (c.colsb[7], c.rows[7]) = (64, 16);
    // SAFETY: `c` is a valid palette-1 configuration, 64-byte aligned.
    unsafe { asm!("ldtilecfg [{}]", in(reg) &c, options(nostack, readonly)) };
}

/// Returns the tiles to their initial state (the end of a pass).
pub(super) unsafe fn release() {
    // SAFETY: valid after `configure`, and harmless without it.
    unsafe { asm!("tilerelease", options(nostack, nomem)) };
}

macro_rules! per_sum_tile {
    ($c:expr, $body:ident) => {
        match $c {
            0 => $body!("tmm0"),
            1 => $body!("tmm1"),
            2 => $body!("tmm2"),
            _ => $body!("tmm3"),
        }
    };
}

/// Adds `A · B` to the sums `tmm0`… for `N` blocks of 16 columns, over `len` values of the
/// inner dimension (a multiple of 16): A is 16 rows from `a` (row stride `a_stride` bytes), B
/// the pairs of rows `[len / 2][16 N][2]` from `b`; 32 values a step, and 16 for a last half.
unsafe fn accumulate<const N: usize>(a: *const u16, a_stride: usize, b: *const u16, len: usize) {
    let b_stride = 64 * N;
    let mut k0 = 0;
    // SAFETY (whole body): the callers bound A's 16 rows of `len` values and B's `len / 2`
    // rows of `16 N` pairs; the tiles are configured.
    unsafe {
        while k0 < len {
            let whole = len - k0 >= 32;
            let a_step = a.add(k0);
            if whole {
                asm!("tileloadd tmm5, [{p} + {s}*1]", p = in(reg) a_step, s = in(reg) a_stride, options(nostack, readonly));
            } else {
                asm!("tileloadd tmm4, [{p} + {s}*1]", p = in(reg) a_step, s = in(reg) a_stride, options(nostack, readonly));
            }
            for c in 0..N {
                // Pairs of rows k0 / 2 onwards, columns 16c onwards.
                let b_step = b.add((k0 / 2) * 32 * N + 32 * c);
                if whole {
                    asm!("tileloadd tmm7, [{p} + {s}*1]", p = in(reg) b_step, s = in(reg) b_stride, options(nostack, readonly));
                    macro_rules! dp {
                        ($t:literal) => {
                            asm!(concat!("tdpbf16ps ", $t, ", tmm5, tmm7"), options(nostack, nomem))
                        };
                    }
                    per_sum_tile!(c, dp);
                } else {
                    asm!("tileloadd tmm6, [{p} + {s}*1]", p = in(reg) b_step, s = in(reg) b_stride, options(nostack, readonly));
                    macro_rules! dp {
                        ($t:literal) => {
                            asm!(concat!("tdpbf16ps ", $t, ", tmm4, tmm6"), options(nostack, nomem))
                        };
                    }
                    per_sum_tile!(c, dp);
                }
            }
            k0 += if whole { 32 } else { 16 };
        }
    }
}

/// `out[p][16c + j] = bias[16c + j] + Σ_k a[p][k] · w[k][16c + j]` for the 16 rows of `a`
/// (row stride `k`, a multiple of 16 up to 64) and `16 NC` columns: `w` packed as `[k / 2][16
/// NC][2]`; `out` rows of 64 f32. Requires [`configure`] on this thread.
pub(super) unsafe fn product<const NC: usize>(a: &[u16], k: usize, w: &[u16], bias: Option<&[f32]>, out: &mut [f32]) {
    debug_assert!(NC <= 4 && k.is_multiple_of(16) && (16..=64).contains(&k));
    debug_assert!(a.len() >= ROWS * k && w.len() >= k * 16 * NC && out.len() >= ROWS * 64);
    debug_assert!(bias.is_none_or(|b| b.len() >= 16 * NC));
    let a_stride = 2 * k;
    // SAFETY (whole body): the asserts bound every tile's reach: A rows of `k` values, B rows
    // of `16 NC` pairs over `k / 2` rows, sums of 16 rows of 64 f32; the tiles are configured.
    unsafe {
        for c in 0..NC {
            match bias {
                Some(b) => {
                    let p = b.as_ptr().add(16 * c);
                    macro_rules! load_bias {
                        ($t:literal) => {
                            asm!(concat!("tileloadd ", $t, ", [{p} + {s}*1]"), p = in(reg) p, s = in(reg) 0usize, options(nostack, readonly))
                        };
                    }
                    per_sum_tile!(c, load_bias);
                }
                None => {
                    macro_rules! zero {
                        ($t:literal) => {
                            asm!(concat!("tilezero ", $t), options(nostack, nomem))
                        };
                    }
                    per_sum_tile!(c, zero);
                }
            }
        }
        accumulate::<NC>(a.as_ptr(), a_stride, w.as_ptr(), k);
        let op = out.as_mut_ptr();
        for c in 0..NC {
            let p = op.add(16 * c);
            macro_rules! store {
                ($t:literal) => {
                    asm!(concat!("tilestored [{p} + {s}*1], ", $t), p = in(reg) p, s = in(reg) 256usize, options(nostack))
                };
            }
            per_sum_tile!(c, store);
        }
    }
}

/// `dwt[j][k] += Σ_p dzt[j][p] · inp[p][k]` for the 64 rows `j` and `16 NK` columns `k`, over
/// `p_len` rows `p` (a multiple of 16 up to 48): `dwt` is `64 × 16 NK` f32, `dzt` `64 × 48`
/// bfloat16 (∂z transposed; zero past the block's rows), `inp` the layer input's rows paired as
/// `[p / 2][16 NK][2]`. Requires [`configure`] on this thread.
pub(super) unsafe fn rank<const NK: usize>(dwt: &mut [f32], dzt: &[u16], inp: &[u16], p_len: usize) {
    let k = 16 * NK;
    debug_assert!(NK <= 4 && p_len.is_multiple_of(16) && p_len <= 48);
    debug_assert!(dwt.len() >= 64 * k && dzt.len() >= 64 * 48 && inp.len() >= p_len * k);
    let (c_stride, a_stride): (usize, usize) = (4 * k, 2 * 48);
    // SAFETY (whole body): the asserts bound every tile's reach: sums of 16 rows of `k` f32
    // inside `dwt`, A rows of 48 values, B rows of `k` pairs over `p_len / 2` rows.
    unsafe {
        let (dp_, ap, bp) = (dwt.as_mut_ptr(), dzt.as_ptr(), inp.as_ptr());
        for jb in 0..4 {
            for c in 0..NK {
                let p = dp_.add(jb * 16 * k + 16 * c);
                macro_rules! load {
                    ($t:literal) => {
                        asm!(concat!("tileloadd ", $t, ", [{p} + {s}*1]"), p = in(reg) p, s = in(reg) c_stride, options(nostack, readonly))
                    };
                }
                per_sum_tile!(c, load);
            }
            accumulate::<NK>(ap.add(jb * 16 * 48), a_stride, bp, p_len);
            for c in 0..NK {
                let p = dp_.add(jb * 16 * k + 16 * c);
                macro_rules! store {
                    ($t:literal) => {
                        asm!(concat!("tilestored [{p} + {s}*1], ", $t), p = in(reg) p, s = in(reg) c_stride, options(nostack))
                    };
                }
                per_sum_tile!(c, store);
            }
        }
    }
}
