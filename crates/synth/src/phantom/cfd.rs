//! CFD phantoms: instants of a buoyant plume and of a forced round jet solved with PhiFlow, an
//! incompressible-flow solver, by `phantoms/cfd/make_cfd.py` (its `provenance.json` records
//! the solver, parameters, steps, seed and command). They are an independent class from the
//! procedural jets: tune a method on one class and report on the other (`docs/phantoms.md`).
//!
//! The volumes are embedded in the crate (`include_bytes!`), so they need no file at run time
//! and work from any directory.
//!
//! # Conventions
//! - **Box**: the simulation domain, [`CELLS`] cells of [`CELL_MM`] mm centred at the origin:
//!   x, z ∈ [−12, 12] mm, y ∈ [−18, 18] mm ([`domain`]).
//! - **Axis**: both flows rise along world **+y** from the bottom face (y = −18 mm) and leave
//!   through the open top face; unlike the procedural jets, which flow along +x.
//! - **Values**: the transported marker (smoke density), dimensionless, held at 1 in the
//!   source or nozzle, clipped to ≥ 0.
//! - **Time**: solver steps since the fluid was at rest (time step Δt = 2 solver time units,
//!   the time one cell width takes at unit speed). Only the stored [`STEPS`] exist; there is
//!   no interpolation in time.
//! - **Storage**: float32 `.npy` of shape `(nz, ny, nx)`, x fastest, cell-centred (as
//!   [`Volume`]).

use fluidnerf_core::glam::{DVec3, Vec3};
use fluidnerf_core::{Aabb, ScalarField, Volume};
use serde::{Deserialize, Serialize};

use crate::SynthError;

/// Cells of the simulation grid along x, y, z.
pub const CELLS: [usize; 3] = [48, 72, 48];
/// Width of one simulation cell in world units, mm.
pub const CELL_MM: f64 = 0.5;
/// Solver steps of the stored instants, ascending: 50 → 52 and 50 → 60 are 2 and 10 steps
/// apart, 40 is an earlier, less developed instant.
pub const STEPS: [u32; 4] = [40, 50, 52, 60];
/// The instant a static CFD phantom uses unless told otherwise: the most developed one.
pub const DEFAULT_STEP: u32 = 60;

/// Which CFD flow.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CfdCase {
    /// Buoyant (Boussinesq) plume from a hot spot near the bottom.
    Plume,
    /// Forced round jet from a nozzle on the bottom face.
    Jet,
}

struct Embedded {
    case: CfdCase,
    step: u32,
    npy: &'static [u8],
}

macro_rules! embed {
    ($case:expr, $step:literal, $file:literal) => {
        Embedded { case: $case, step: $step, npy: include_bytes!(concat!("../../phantoms/cfd/", $file)) }
    };
}

static EMBEDDED: [Embedded; 8] = [
    embed!(CfdCase::Plume, 40, "plume_s0040.npy"),
    embed!(CfdCase::Plume, 50, "plume_s0050.npy"),
    embed!(CfdCase::Plume, 52, "plume_s0052.npy"),
    embed!(CfdCase::Plume, 60, "plume_s0060.npy"),
    embed!(CfdCase::Jet, 40, "jet_s0040.npy"),
    embed!(CfdCase::Jet, 50, "jet_s0050.npy"),
    embed!(CfdCase::Jet, 52, "jet_s0052.npy"),
    embed!(CfdCase::Jet, 60, "jet_s0060.npy"),
];

/// The simulation domain in world mm: [`CELLS`] × [`CELL_MM`], centred at the origin.
pub fn domain() -> Aabb {
    let half = DVec3::new(CELLS[0] as f64, CELLS[1] as f64, CELLS[2] as f64) * (0.5 * CELL_MM);
    Aabb::new(-half, half)
}

impl CfdCase {
    pub fn name(self) -> &'static str {
        match self {
            CfdCase::Plume => "plume",
            CfdCase::Jet => "jet",
        }
    }

    /// The embedded `.npy` bytes of the instant at solver step `step`, if stored.
    pub fn npy_bytes(self, step: u32) -> Option<&'static [u8]> {
        EMBEDDED.iter().find(|e| e.case == self && e.step == step).map(|e| e.npy)
    }

    /// Decodes the instant at solver step `step` onto [`domain`].
    pub fn instant(self, step: u32) -> Result<Volume, SynthError> {
        let name = format!("{}_s{step:04}.npy", self.name());
        let bytes = self.npy_bytes(step).ok_or_else(|| {
            SynthError::invalid(
                "phantom.cfd_step",
                format!("no {} instant at step {step}; stored: {STEPS:?}", self.name()),
            )
        })?;
        let vol =
            decode_npy(bytes, domain()).map_err(|problem| SynthError::Embedded { name: name.clone(), problem })?;
        if vol.dims != CELLS {
            return Err(SynthError::Embedded { name, problem: format!("grid {:?}, expected {CELLS:?}", vol.dims) });
        }
        Ok(vol)
    }
}

/// A note for a data set's record: what the phantom is, its axis, units and times.
pub fn note(case: CfdCase) -> String {
    let what = match case {
        CfdCase::Plume => "buoyant (Boussinesq) plume from a hot spot near the bottom",
        CfdCase::Jet => "forced round jet from a 3 mm nozzle on the bottom face",
    };
    let b = domain();
    format!(
        "CFD {what}, solved with PhiFlow (crates/synth/phantoms/cfd/provenance.json); flow along +y; \
         box = simulation domain [{}, {}] x [{}, {}] x [{}, {}] mm, {CELL_MM} mm cells; \
         values = smoke marker (1 at the source); times = solver steps (stored {STEPS:?})",
        b.min.x, b.max.x, b.min.y, b.max.y, b.min.z, b.max.z
    )
}

/// Checks that `time` names a stored instant (a whole solver step in [`STEPS`]).
pub fn step_of(time: f64) -> Option<u32> {
    STEPS.iter().copied().find(|&s| s as f64 == time)
}

/// Decodes a little-endian float32, C-order, three-dimensional `.npy` (format 1.0–3.0) of
/// shape `(nz, ny, nx)` into a volume filling `aabb`. The error says what is wrong.
pub fn decode_npy(bytes: &[u8], aabb: Aabb) -> Result<Volume, String> {
    const MAGIC: &[u8] = b"\x93NUMPY";
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err("not a .npy file (no magic string)".into());
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        v => return Err(format!(".npy format version {v} is not supported")),
    };
    let header = bytes
        .get(start..start + header_len)
        .and_then(|h| std::str::from_utf8(h).ok())
        .ok_or("truncated or non-text .npy header")?;
    let compact: String = header.chars().filter(|c| !c.is_whitespace()).collect();
    if !compact.contains("'descr':'<f4'") {
        return Err(format!("only little-endian float32 ('<f4') is supported, header {header:?}"));
    }
    if !compact.contains("'fortran_order':False") {
        return Err("only C-order arrays are supported".into());
    }
    let shape = compact
        .split("'shape':(")
        .nth(1)
        .and_then(|rest| rest.split(')').next())
        .ok_or_else(|| format!("no shape in header {header:?}"))?;
    let shape: Vec<usize> = shape
        .split(',')
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>().map_err(|e| format!("bad shape entry {s:?}: {e}")))
        .collect::<Result<_, _>>()?;
    let [nz, ny, nx] = shape[..] else {
        return Err(format!("expected a 3-D array (nz, ny, nx), got shape {shape:?}"));
    };
    let payload = &bytes[start + header_len..];
    // Checked: a damaged shape's product can wrap around to the payload's length.
    let Some(need) = [nx, ny, nz, 4].iter().try_fold(1usize, |n, &d| n.checked_mul(d)) else {
        return Err(format!("shape {shape:?} needs more data bytes than any file holds"));
    };
    if need == 0 || payload.len() != need {
        return Err(format!("shape {shape:?} needs {need} data bytes, found {}", payload.len()));
    }
    let data = payload.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
    Ok(Volume::from_vec([nx, ny, nz], aabb, data))
}

/// A CFD flow at its stored instants, placed in world coordinates on [`domain`] (zero outside).
#[derive(Clone, Debug)]
pub struct CfdPhantom {
    pub case: CfdCase,
    /// Every stored instant, by ascending solver step.
    pub instants: Vec<(u32, Volume)>,
    /// The instant used when no time is given (static data sets).
    pub static_step: u32,
}

impl CfdPhantom {
    /// Decodes every stored instant of `case`; `static_step` (default [`DEFAULT_STEP`]) must
    /// be one of [`STEPS`].
    pub fn new(case: CfdCase, static_step: Option<u32>) -> Result<Self, SynthError> {
        let static_step = static_step.unwrap_or(DEFAULT_STEP);
        if !STEPS.contains(&static_step) {
            return Err(SynthError::invalid(
                "phantom.cfd_step",
                format!("no instant at step {static_step}; stored: {STEPS:?}"),
            ));
        }
        let instants = STEPS.iter().map(|&s| Ok((s, case.instant(s)?))).collect::<Result<_, SynthError>>()?;
        Ok(CfdPhantom { case, instants, static_step })
    }

    /// The instant at frame time `time` (a solver step), or the static one for `None`. A time
    /// between stored steps takes the nearest stored step.
    pub fn instant_at(&self, time: Option<f64>) -> &Volume {
        let step = time.map_or(self.static_step as f64, |t| t);
        let nearest = self
            .instants
            .iter()
            .min_by(|a, b| (a.0 as f64 - step).abs().total_cmp(&(b.0 as f64 - step).abs()))
            .expect("a CFD phantom holds at least one instant");
        &nearest.1
    }

    /// The ground truth at `time` on the grid `dims` filling `aabb`: the stored instant itself
    /// when the grids coincide, else trilinear resampling of it (zero outside the domain).
    pub fn truth(&self, time: Option<f64>, dims: [usize; 3], aabb: &Aabb) -> Volume {
        let vol = self.instant_at(time);
        if vol.dims == dims && vol.aabb == *aabb {
            vol.clone()
        } else {
            vol.resample(dims, *aabb)
        }
    }
}

impl ScalarField for CfdPhantom {
    fn eval(&self, points: &[Vec3], time: f64, out: &mut [f32]) {
        // The generator passes time 0 for static data sets; step 0 is the fluid at rest.
        let vol = self.instant_at(if time == 0.0 { None } else { Some(time) });
        vol.eval(points, time, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The generator's record of what it wrote.
    fn provenance() -> serde_json::Value {
        serde_json::from_str(include_str!("../../phantoms/cfd/provenance.json")).expect("provenance.json parses")
    }

    /// FNV-1a, 64 bits (the generator records it over the array's float32 bytes).
    fn fnv1a64(bytes: &[u8]) -> u64 {
        bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3))
    }

    #[test]
    fn embedded_instants_match_the_generators_record() {
        let prov = provenance();
        let grid: Vec<usize> = serde_json::from_value(prov["grid"]["cells_xyz"].clone()).expect("grid.cells_xyz");
        assert_eq!(grid, CELLS);
        assert_eq!(prov["grid"]["world_cell_mm"].as_f64(), Some(CELL_MM));
        assert_eq!(prov["grid"]["flow_axis"].as_str(), Some("+y"));
        let steps: Vec<u32> = serde_json::from_value(prov["steps_saved"].clone()).expect("steps_saved");
        assert_eq!(steps, STEPS);
        let sp = CELL_MM;
        for case in [CfdCase::Plume, CfdCase::Jet] {
            let record = prov[case.name()]["instants"].as_array().expect("instants");
            assert_eq!(record.len(), STEPS.len(), "{}", case.name());
            for r in record {
                let step = r["step"].as_u64().expect("step") as u32;
                let what = format!("{} step {step}", case.name());
                assert_eq!(r["file"].as_str(), Some(format!("{}_s{step:04}.npy", case.name()).as_str()));
                let vol = case.instant(step).expect("decodes");
                let shape: Vec<usize> = serde_json::from_value(r["shape"].clone()).expect("shape");
                assert_eq!(shape, vec![vol.dims[2], vol.dims[1], vol.dims[0]], "{what}");
                assert_eq!(vol.aabb, domain());
                assert!(vol.data.iter().all(|v| v.is_finite() && *v >= 0.0), "{what}: finite and non-negative");
                let bytes: Vec<u8> = vol.data.iter().flat_map(|v| v.to_le_bytes()).collect();
                assert_eq!(format!("{:016x}", fnv1a64(&bytes)), r["fnv1a64"].as_str().expect("fnv1a64"), "{what}");
                let sum: f64 = vol.data.iter().map(|&v| v as f64).sum();
                let max = vol.min_max().1 as f64;
                assert!((sum - r["sum"].as_f64().expect("sum")).abs() <= 1e-9 * sum, "{what}: sum {sum}");
                assert_eq!(max, r["max"].as_f64().expect("max"), "{what}");
                assert!(sum > 100.0 && max > 0.5, "{what}: a real plume, not an empty box");
                // Centroid in cell indices, then in world mm: on the axis, above the source.
                let mut c = DVec3::ZERO;
                for k in 0..vol.dims[2] {
                    for j in 0..vol.dims[1] {
                        for i in 0..vol.dims[0] {
                            c += vol.get(i, j, k) as f64 * DVec3::new(i as f64, j as f64, k as f64);
                        }
                    }
                }
                let c = c / sum;
                let recorded: [f64; 3] = serde_json::from_value(r["centroid_ijk"].clone()).expect("centroid");
                assert!((c - DVec3::from(recorded)).abs().max_element() < 1e-6, "{what}: centroid {c}");
                let world = domain().min + (c + 0.5) * sp;
                assert!(world.x.abs() < 3.0 && world.z.abs() < 3.0, "{what}: centroid {world} off the y axis");
                assert!(world.y > domain().min.y + 3.0, "{what}: centroid {world} not above the source");
            }
        }
    }

    #[test]
    fn instants_differ_and_grow_with_time() {
        for case in [CfdCase::Plume, CfdCase::Jet] {
            let p = CfdPhantom::new(case, None).expect("builds");
            let at = |s: u32| p.instant_at(Some(s as f64));
            assert_ne!(at(50).data, at(52).data, "{}: 2 steps apart", case.name());
            assert_ne!(at(50).data, at(60).data, "{}: 10 steps apart", case.name());
            let d2: f64 = at(50).data.iter().zip(&at(52).data).map(|(a, b)| (a - b).abs() as f64).sum();
            let d10: f64 = at(50).data.iter().zip(&at(60).data).map(|(a, b)| (a - b).abs() as f64).sum();
            assert!(d10 > d2, "{}: 10 steps change the field more than 2 ({d10} vs {d2})", case.name());
            // Marker keeps entering from the source until it leaves at the top.
            let sum = |s: u32| at(s).data.iter().map(|&v| v as f64).sum::<f64>();
            assert!(sum(40) < sum(60), "{}: marker accumulates", case.name());
            assert_eq!(p.instant_at(None), at(DEFAULT_STEP));
        }
    }

    #[test]
    fn truth_is_the_stored_grid_or_a_resampling_of_it() {
        let p = CfdPhantom::new(CfdCase::Plume, Some(50)).expect("builds");
        let box_ = domain();
        let exact = p.truth(None, CELLS, &box_);
        assert_eq!(exact.data, p.instant_at(Some(50.0)).data);
        let coarse = p.truth(Some(60.0), [24, 36, 24], &box_);
        let ratio = coarse.data.iter().map(|&v| v as f64).sum::<f64>() * 8.0
            / p.instant_at(Some(60.0)).data.iter().map(|&v| v as f64).sum::<f64>();
        assert!((ratio - 1.0).abs() < 0.05, "resampling keeps the integral, ratio {ratio}");
        // Zero outside the domain.
        let mut out = [1.0f32];
        p.eval(&[Vec3::new(0.0, 30.0, 0.0)], 0.0, &mut out);
        assert_eq!(out[0], 0.0);
        assert!(matches!(CfdPhantom::new(CfdCase::Jet, Some(51)), Err(SynthError::Invalid { .. })));
    }

    #[test]
    fn npy_decoder_rejects_what_it_cannot_read() {
        let b = domain();
        let npy = |descr: &str, shape: &str, payload: usize| {
            let mut h = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
            while (10 + h.len() + 1) % 64 != 0 {
                h.push(' ');
            }
            h.push('\n');
            let mut v = b"\x93NUMPY\x01\x00".to_vec();
            v.extend_from_slice(&(h.len() as u16).to_le_bytes());
            v.extend_from_slice(h.as_bytes());
            v.extend(std::iter::repeat_n(0u8, payload));
            v
        };
        let ok = decode_npy(&npy("<f4", "(2, 3, 4)", 96), b).expect("decodes");
        assert_eq!(ok.dims, [4, 3, 2]);
        assert!(decode_npy(&npy("<f8", "(2, 3, 4)", 192), b).expect_err("f8").contains("float32"));
        assert!(decode_npy(&npy("<f4", "(6, 4)", 96), b).expect_err("2-D").contains("3-D"));
        assert!(decode_npy(&npy("<f4", "(2, 3, 4)", 95), b).expect_err("short").contains("bytes"));
        // 2 · (2^63 + 12) wraps around to 24 values, the payload's.
        let wraps = npy("<f4", "(1, 2, 9223372036854775820)", 96);
        assert!(decode_npy(&wraps, b).expect_err("wraps").contains("more data bytes than any file holds"));
        assert!(decode_npy(b"garbage!!!!!", b).expect_err("magic").contains("magic"));
    }
}
