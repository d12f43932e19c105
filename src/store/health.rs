//! The health check of every element the store builds (at the start and
//! after every cut, split, merge or refinement).
//!
//! An element is healthy when its stiffness `K_e` has exactly the six
//! rigid modes in its null space and a seventh eigenvalue `λ₇` of at least
//! [`HealthFloors::stiffness_ratio`] times its largest `λ_max` (no soft
//! mode), and when every node's share of its lumped mass is at least
//! [`HealthFloors::mass_fraction`] times the mean share `1/k` (so that no
//! node ends with a negligible mass: a node's mass is then at least that
//! fraction of the mean nodal mass `ρ V_e / k_e` of its elements). The
//! spectrum comes from [`cleave_kernels::spectrum`]: exact and closed form
//! for tetrahedra; for the other elements `λ_max` by power iteration and
//! the floor on `λ₇` certified by a Cholesky factor (which exists exactly
//! when `λ₇` reaches it), both one element per SIMD lane (`cleave bench
//! --only simd`, AMD EPYC, AVX-512: 0.37 µs per tetrahedron; in a run of
//! 32 hexahedra, 24 x 24 `K_e`, 2.7 µs each on an Intel Xeon, against 5.1
//! µs for the estimate of `λ₇` by inverse iteration it replaced: `cargo
//! bench --bench cut -- run_of_32`), so the check stays on. A failure is
//! an error naming the element.

use cleave_kernels::spectrum::{stiffness_certificates, tet_spectra, Certificate};
use rayon::prelude::*;

use super::{BasisError, Batch};

/// Floors every built element must meet.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HealthFloors {
    /// Smallest `λ₇ / λ_max` of an element stiffness. Default `1e-6`.
    pub stiffness_ratio: f64,
    /// Smallest lumped mass share of a node of an element, relative to the
    /// mean share `1/k`. Default `0.01`.
    pub mass_fraction: f64,
    /// Largest `|K_e q| / λ_max` over the unit rigid modes `q`. Default
    /// `1e-8`.
    pub rigid_residual: f64,
}

impl Default for HealthFloors {
    /// Measured on every element of the shipped scenes and of hundreds of
    /// random cuts through the bunny and random convex boxes: healthy
    /// elements (tetrahedra of the TetGen bunnies, hexahedra, random convex
    /// cells, harmonic elements, cut pieces) have `λ₇ / λ_max` above `2e-5`
    /// and mass shares above `0.1 / k`; rigid residuals are rounding
    /// (`1e-13` and below). The floors leave an order of magnitude of margin
    /// below those and far above what a soft mode gives (`1e-9` to `1e-14`).
    fn default() -> Self {
        HealthFloors { stiffness_ratio: 1e-6, mass_fraction: 0.01, rigid_residual: 1e-8 }
    }
}

impl HealthFloors {
    /// Checks every floor is a number `>= 0` (infinity switches the rigid
    /// residual check off).
    pub fn check(&self) -> Result<(), crate::param::ParamError> {
        let floors = [
            ("stiffness_ratio", self.stiffness_ratio),
            ("mass_fraction", self.mass_fraction),
            ("rigid_residual", self.rigid_residual),
        ];
        match floors.iter().find(|(_, v)| !(*v >= 0.0)) {
            Some(&(name, v)) => Err(crate::param::ParamError::new(name, v, "must be a number >= 0")),
            None => Ok(()),
        }
    }
}

/// Checks every entry of every batch `b` from entry `first[b]` on against
/// `floors`; on failure, names, in the first batch with a failing entry,
/// the failing entry with the smallest element id (so the error does not
/// depend on the thread count).
pub(super) fn check_all(batches: &[Batch], first: &[usize], floors: &HealthFloors) -> Result<(), BasisError> {
    first_failure(batches, first, assess(batches, first, floors))
}

/// The verdict on every entry of every batch `b` from entry `first[b]` on:
/// the first of `floors` it fails, if any.
pub(super) fn assess(batches: &[Batch], first: &[usize], floors: &HealthFloors) -> Vec<Vec<Result<(), BasisError>>> {
    let certificates = certificates(batches, first, floors.stiffness_ratio);
    (batches.iter().zip(first).zip(certificates))
        .map(|((batch, &from), certificates)| verdicts(batch, from, &certificates, floors))
        .collect()
}

/// The error [`check_all`] names for `verdicts` (of [`assess`] from the
/// same `first`), if any.
pub(super) fn first_failure(
    batches: &[Batch],
    first: &[usize],
    verdicts: Vec<Vec<Result<(), BasisError>>>,
) -> Result<(), BasisError> {
    for ((batch, &from), verdicts) in batches.iter().zip(first).zip(verdicts) {
        let failures = verdicts.into_iter().enumerate().filter_map(|(i, r)| r.err().map(|e| (from + i, e)));
        if let Some((_, e)) = failures.min_by_key(|(i, _)| batch.elements[*i]) {
            return Err(e);
        }
    }
    Ok(())
}

/// The verdict on every entry of `batch` from entry `from` on, whose
/// entries have the `certificates`.
fn verdicts(
    batch: &Batch,
    from: usize,
    certificates: &[Certificate],
    floors: &HealthFloors,
) -> Vec<Result<(), BasisError>> {
    let k = batch.k;
    (from..batch.len())
        .into_par_iter()
        .map(|i| {
            let element = batch.elements[i] as usize;
            let share = &batch.mass_fraction[i * k..(i + 1) * k];
            if let Some(a) = (0..k).find(|&a| !(share[a] * k as f64 >= floors.mass_fraction)) {
                let node = batch.nodes[i * k + a] as usize;
                let fraction = share[a] * k as f64;
                return Err(BasisError::LightNode { element, node, fraction, floor: floors.mass_fraction });
            }
            let c = certificates[i - from];
            if !(c.rigid_residual <= floors.rigid_residual) {
                return Err(BasisError::RigidModes { element, residual: c.rigid_residual });
            }
            if !c.stiff {
                // (the estimate, for the message: a rare path)
                let ratio = batch.stiffness_spectrum(i).ratio();
                return Err(BasisError::SoftElement { element, ratio, floor: floors.stiffness_ratio });
            }
            Ok(())
        })
        .collect()
}

/// Elements whose spectra one task estimates together: a few SIMD lane
/// widths (the matrices gathered for them stay in cache), more for
/// tetrahedra (no matrix).
const SPECTRUM_RUN: usize = 32;
const TET_RUN: usize = 128;

/// Whether `λ₇ ≥ floor λ_max` for every entry of every batch `b` from
/// entry `first[b]` on, with its `λ_max` and rigid residual: closed form
/// for tetrahedra, else certified from its `K_e`, runs of entries side by
/// side in SIMD lanes (each entry's certificate the same whichever run
/// holds it), the runs of all batches in one parallel pass (a cut makes a
/// dozen batches, most of a few elements).
fn certificates(batches: &[Batch], first: &[usize], floor: f64) -> Vec<Vec<Certificate>> {
    let runs: Vec<(usize, std::ops::Range<usize>)> = batches
        .iter()
        .zip(first)
        .enumerate()
        .flat_map(|(b, (batch, &from))| {
            let run = if batch.is_tet() { TET_RUN } else { SPECTRUM_RUN };
            (from..batch.len()).step_by(run).map(move |start| (b, start..(start + run).min(batch.len())))
        })
        .collect();
    let found: Vec<Vec<Certificate>> = runs
        .par_iter()
        .map_init(Vec::new, |ke, (b, range)| {
            let batch = &batches[*b];
            let (k, n) = (batch.k, 3 * batch.k);
            let x = &batch.rest[range.start * k..range.end * k];
            if batch.is_tet() {
                // the nonzero spectrum of a 6 x 6 matrix, exactly
                let mut spectra = vec![Default::default(); range.len()];
                let (g, volume) = (&batch.stress_grads[range.start * 4..range.end * 4], &batch.volume[range.clone()]);
                tet_spectra(x, g, volume, batch.lame.0, batch.lame.1, &mut spectra);
                return (spectra.iter())
                    .map(|s| Certificate {
                        lambda_max: s.lambda_max,
                        rigid_residual: s.rigid_residual,
                        stiff: s.ratio() >= floor,
                    })
                    .collect();
            }
            ke.resize(range.len() * n * n, 0.0);
            for (i, m) in range.clone().zip(ke.chunks_exact_mut(n * n)) {
                batch.element_matrix_into(i, m);
            }
            let mut out = vec![Certificate::default(); range.len()];
            stiffness_certificates(ke, batch.rigid_modes(range.clone()), floor, &mut out);
            out
        })
        .collect();
    let mut per_batch: Vec<Vec<Certificate>> =
        batches.iter().zip(first).map(|(b, &from)| Vec::with_capacity(b.len() - from)).collect();
    for ((b, _), run) in runs.iter().zip(found) {
        per_batch[*b].extend(run);
    }
    per_batch
}
