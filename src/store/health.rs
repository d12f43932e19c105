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
//! for tetrahedra, estimated by power and inverse iteration for the other
//! elements, both one element per SIMD lane (`cleave bench --only simd`,
//! AMD EPYC, AVX-512: 0.37 µs per tetrahedron, 4.3 µs per 24 x 24 `K_e`),
//! so the check stays on. A failure is an error naming the element.

use cleave_kernels::spectrum::{stiffness_spectra, tet_spectra, RigidModes, Spectrum};
use rayon::prelude::*;

use super::{BasisError, Batch, ElementKind};

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

/// Computes `λ₇ / λ_max` of every entry of every batch `b` from entry
/// `first[b]` on into its `stiffness_ratio` and checks those entries
/// against `floors`; on failure, names, in the first batch with a failing
/// entry, the failing entry with the smallest element id (so the error
/// does not depend on the thread count).
pub(super) fn check_all(batches: &mut [Batch], first: &[usize], floors: &HealthFloors) -> Result<(), BasisError> {
    let verdicts = assess(batches, first, floors);
    record(batches, first, verdicts)
}

/// The verdict on every entry of every batch `b` from entry `first[b]` on:
/// its `λ₇ / λ_max`, or the first of `floors` it fails.
pub(super) fn assess(batches: &[Batch], first: &[usize], floors: &HealthFloors) -> Vec<Vec<Result<f64, BasisError>>> {
    let spectra = spectra(batches, first);
    (batches.iter().zip(first).zip(spectra))
        .map(|((batch, &from), spectra)| verdicts(batch, from, &spectra, floors))
        .collect()
}

/// Stores the ratios of `verdicts` (of [`assess`] from the same `first`, 0
/// for a failed entry) in the batches and returns the error [`check_all`]
/// names, if any.
pub(super) fn record(
    batches: &mut [Batch],
    first: &[usize],
    verdicts: Vec<Vec<Result<f64, BasisError>>>,
) -> Result<(), BasisError> {
    let mut first_failure: Option<BasisError> = None;
    for ((batch, &from), verdicts) in batches.iter_mut().zip(first).zip(verdicts) {
        let mut worst: Option<BasisError> = None;
        batch.stiffness_ratio.resize(batch.len(), 0.0);
        for (i, r) in verdicts.into_iter().enumerate() {
            batch.stiffness_ratio[from + i] = match r {
                Ok(ratio) => ratio,
                Err(e) => {
                    let first = worst.as_ref().is_none_or(|w| (batch.elements[from + i] as usize) < w.element());
                    if first {
                        worst = Some(e);
                    }
                    0.0
                }
            };
        }
        if first_failure.is_none() {
            first_failure = worst;
        }
    }
    first_failure.map_or(Ok(()), Err)
}

/// The verdict on every entry of `batch` from entry `from` on, whose
/// entries have the `spectra`.
fn verdicts(batch: &Batch, from: usize, spectra: &[Spectrum], floors: &HealthFloors) -> Vec<Result<f64, BasisError>> {
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
            let s = spectra[i - from];
            if !(s.rigid_residual <= floors.rigid_residual) {
                return Err(BasisError::RigidModes { element, residual: s.rigid_residual });
            }
            let ratio = s.ratio();
            if !(ratio >= floors.stiffness_ratio) {
                return Err(BasisError::SoftElement { element, ratio, floor: floors.stiffness_ratio });
            }
            Ok(ratio)
        })
        .collect()
}

/// Elements whose spectra one task estimates together: a few SIMD lane
/// widths (the matrices gathered for them stay in cache), more for
/// tetrahedra (no matrix).
const SPECTRUM_RUN: usize = 32;
const TET_RUN: usize = 128;

/// The spectrum of every entry of every batch `b` from entry `first[b]`
/// on: closed form for tetrahedra, else estimated from its `K_e`, runs of
/// entries side by side in SIMD lanes (each entry's estimate the same
/// whichever run holds it), the runs of all batches in one parallel pass
/// (a cut makes a dozen batches, most of a few elements).
fn spectra(batches: &[Batch], first: &[usize]) -> Vec<Vec<Spectrum>> {
    let runs: Vec<(usize, std::ops::Range<usize>)> = batches
        .iter()
        .zip(first)
        .enumerate()
        .flat_map(|(b, (batch, &from))| {
            let run = if batch.is_tet() { TET_RUN } else { SPECTRUM_RUN };
            (from..batch.len()).step_by(run).map(move |start| (b, start..(start + run).min(batch.len())))
        })
        .collect();
    let estimates: Vec<Vec<Spectrum>> = runs
        .par_iter()
        .map_init(Vec::new, |ke, (b, range)| {
            let batch = &batches[*b];
            let (k, n) = (batch.k, 3 * batch.k);
            let mut out = vec![Spectrum::default(); range.len()];
            let x = &batch.rest[range.start * k..range.end * k];
            if batch.is_tet() {
                // the nonzero spectrum of a 6 x 6 matrix
                let (g, volume) = (&batch.stress_grads[range.start * 4..range.end * 4], &batch.volume[range.clone()]);
                tet_spectra(x, g, volume, batch.lame.0, batch.lame.1, &mut out);
                return out;
            }
            ke.resize(range.len() * n * n, 0.0);
            for (i, m) in range.clone().zip(ke.chunks_exact_mut(n * n)) {
                batch.element_matrix_into(i, m);
            }
            // a polynomial basis moves rigidly by its first (constant)
            // coefficient and the identity's coefficients
            let modes = if batch.kind == ElementKind::Dg { RigidModes::Modal(x) } else { RigidModes::Nodal(x) };
            stiffness_spectra(ke, modes, &mut out);
            out
        })
        .collect();
    let mut per_batch: Vec<Vec<Spectrum>> =
        batches.iter().zip(first).map(|(b, &from)| Vec::with_capacity(b.len() - from)).collect();
    for ((b, _), run) in runs.iter().zip(estimates) {
        per_batch[*b].extend(run);
    }
    per_batch
}
